"""Live curves of a sweep in TensorBoard: ``python -m jaxlc.sweep --tensorboard DIR``.

One run per model (``DIR/m03_s0_k1_D4000/``, TensorBoard's run selector lists them), written
at every chunk boundary by the lead process, with tensorboardX (no TensorFlow needed):

    train/return_last100    mean return of the model's last <= 100 finished episodes
    train/success_last100   their success rate
    train/critic_loss       mean critic loss over the chunk's updating steps
    train/mean_q            mean Q of the chunk's batches
    train/episodes          finished episodes
    reward/NAME_last100     each reward term's mean over those episodes (env.reward_terms)
    speed/env_steps_per_s   the whole grid's env-steps/s over the chunk

The x axis is the model's env-steps. Each model's hyperparameters (its grid cell and seed)
are its run's text and hparams entry. The numbers are those of ``RUN_DIR/metrics/``:
``episodes.npz`` (returns, reasons, reward terms) and ``steps.npz`` (losses), read at the
chunk's end.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jaxlc.sim.reward import SUCCESS

LAST = 100  # episodes behind return_last100 and success_last100


def run_name(meta: dict[str, Any]) -> str:
    return f"m{meta['model']:02d}_s{meta['seed']}_k{meta['k']}_D{meta['memory']}"


class TensorBoard:
    """A tensorboardX writer per model; ``chunk`` after each chunk, ``close`` at the end."""

    def __init__(self, logdir: Path, metas: list[dict[str, Any]]) -> None:
        try:
            from tensorboardX import SummaryWriter
        except ImportError:
            raise ImportError(
                "--tensorboard needs tensorboardX: pip install -e '.[track]'"
            ) from None
        self.writers = [SummaryWriter(str(Path(logdir) / run_name(m))) for m in metas]
        for w, m in zip(self.writers, metas, strict=True):
            hparams = {k: v for k, v in m.items() if isinstance(v, int | float | str)}
            w.add_text("hparams", "\n".join(f"- {k}: {v}" for k, v in hparams.items()))
            w.add_hparams(hparams, {}, name=".")

    def chunk(
        self,
        env_steps: int,
        log: dict[str, np.ndarray],
        episodes: np.ndarray,
        metrics: dict[str, np.ndarray],
        rate: float,
    ) -> None:
        """Write one point per curve. ``env_steps``: each model's so far; ``log``: the
        models' episode logs ``(models, max_episodes)`` (``log["terms"]``: each reward term's, by
        name); ``episodes (models,)`` finished;
        ``metrics``: the chunk's step metrics ``(steps, models)``; ``rate``: env-steps/s."""
        for i, w in enumerate(self.writers):
            n = int(min(episodes[i], log["ret"].shape[1]))
            lo = max(0, n - LAST)
            if n:
                w.add_scalar("train/return_last100", float(log["ret"][i, lo:n].mean()), env_steps)
                ok = float((log["reason"][i, lo:n] == SUCCESS).mean())
                w.add_scalar("train/success_last100", ok, env_steps)
                for name, col in log.get("terms", {}).items():
                    w.add_scalar(f"reward/{name}_last100", float(col[i, lo:n].mean()), env_steps)
            for name in ("critic_loss", "mean_q"):
                v = metrics[name][:, i]
                if np.isfinite(v).any():
                    w.add_scalar(f"train/{name}", float(np.nanmean(v)), env_steps)
            w.add_scalar("train/episodes", n, env_steps)
            w.add_scalar("speed/env_steps_per_s", rate, env_steps)

    def close(self) -> None:
        for w in self.writers:
            w.close()


def read_scalars(run: Path) -> dict[str, list[tuple[int, float]]]:
    """``{tag: [(step, value), ...]}`` of the scalars in a run directory's event files, in
    the order written (the TFRecord framing read directly: no TensorFlow, no TensorBoard)."""
    from tensorboardX.proto import event_pb2

    out: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(Path(run).glob("events.out.tfevents.*")):
        data, i = path.read_bytes(), 0
        while i + 12 <= len(data):  # u64 length, u32 crc, record, u32 crc
            n = int.from_bytes(data[i : i + 8], "little")
            event = event_pb2.Event.FromString(data[i + 12 : i + 12 + n])
            i += 12 + n + 4
            for v in event.summary.value:
                if v.HasField("simple_value"):
                    out.setdefault(v.tag, []).append((int(event.step), float(v.simple_value)))
    return out
