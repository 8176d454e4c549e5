"""The run directory: one object that owns its layout, so no module spells a path.

    RUN_DIR/config.toml                    resolved config (what ran)
    RUN_DIR/checkpoints/mXX_sY/epNNNNN.*   actor params (msgpack) + metadata (json)
    RUN_DIR/state/train_state.msgpack      the whole training state, for --resume
    RUN_DIR/metrics/episodes.npz           per model: return, steps, reason, reward terms
    RUN_DIR/metrics/steps.npz              per scan step and model: losses, transitions
    RUN_DIR/summary.md, summary.json       last-100-episode success rate and return
    RUN_DIR/lock                           the writing sweep's host, PID, start (jaxlc.study.lock)
    RUN_DIR/eval/eval.json, eval.csv       evaluation rows (python -m jaxlc.evaluate)
    RUN_DIR/eval/cases.npz, traces.npz     per policy and case; the drawn cases
    RUN_DIR/eval/heldout.json, heldout*.csv, collisions.csv, heldout_cases.npz
                                           the held-out lane changes (jaxlc.evaluation.heldout)
    RUN_DIR/eval/convergence.json, .csv    learning speed per model (jaxlc.evaluation.convergence)
    RUN_DIR/figures/*.png, report.md       figures and report of the evaluated run

Every write is atomic (``jaxlc.study.checkpoint.write_bytes_atomic``): a reader sees the old file or
the new one, never half of one.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jaxlc import config
from jaxlc.study import checkpoint


@dataclass(frozen=True)
class RunDir:
    root: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root))

    # --- layout
    @property
    def config(self) -> Path:
        return self.root / "config.toml"

    @property
    def checkpoints(self) -> Path:
        return self.root / checkpoint.CHECKPOINTS_DIR

    def checkpoint(self, model: int, seed: int, episode: int) -> Path:
        return self.checkpoints / f"m{model:02d}_s{seed}" / f"ep{episode:05d}.msgpack"

    @property
    def state(self) -> Path:
        return self.root / "state" / checkpoint.TRAIN_STATE_FILE

    @property
    def lock(self) -> Path:
        return self.root / "lock"

    @property
    def episodes(self) -> Path:
        return self.root / "metrics" / "episodes.npz"

    @property
    def steps(self) -> Path:
        return self.root / "metrics" / "steps.npz"

    @property
    def summary_md(self) -> Path:
        return self.root / "summary.md"

    @property
    def summary_json(self) -> Path:
        return self.root / "summary.json"

    @property
    def eval(self) -> Path:
        return self.root / "eval"

    @property
    def eval_json(self) -> Path:
        return self.eval / "eval.json"

    @property
    def cases(self) -> Path:
        return self.eval / "cases.npz"

    @property
    def traces(self) -> Path:
        return self.eval / "traces.npz"

    @property
    def heldout_json(self) -> Path:
        return self.eval / "heldout.json"

    @property
    def heldout_cases(self) -> Path:
        return self.eval / "heldout_cases.npz"

    @property
    def convergence(self) -> Path:
        return self.eval / "convergence.json"

    def figure(self, name: str) -> Path:
        return self.root / "figures" / name

    @property
    def report(self) -> Path:
        return self.root / "report.md"

    # --- readers and writers
    def is_run(self) -> bool:
        return self.config.is_file()

    def saved_checkpoints(self) -> list[tuple[Path, dict[str, Any]]]:
        """``(path, meta)`` of every checkpoint the sweep saved here (``list_checkpoints``'
        order), each with the model, episode and k it must record; else ``CheckpointError``
        in one line saying what is missing (the directory, a sweep's metadata, or every
        checkpoint: train, or resume a run stopped before its first)."""
        if not self.root.is_dir():
            raise checkpoint.CheckpointError(
                f"run directory {self.root} does not exist; check the path"
            )
        found = [
            (p, json.loads(p.with_suffix(".json").read_text(encoding="utf-8")))
            for p in checkpoint.list_checkpoints(self.root)
        ]
        for p, m in found:
            missing = [k for k in ("model", "episode", "k") if not isinstance(m.get(k), int)]
            if missing:
                raise checkpoint.CheckpointError(
                    f"checkpoint {p} has no {', '.join(missing)} in its JSON, so it was not "
                    "written by python -m jaxlc.sweep; move it out of the run directory"
                )
        if not found and self.state.exists():
            raise checkpoint.CheckpointError(
                f"no checkpoints in {self.checkpoints}: the run stopped before its first; "
                f"continue it with python -m jaxlc.sweep --resume {self.root}"
            )
        if not found:
            raise checkpoint.CheckpointError(
                f"no checkpoints in {self.checkpoints}; train first with "
                f"python -m jaxlc.sweep --out {self.root}"
            )
        return found

    def load_config(self) -> config.Config:
        """The resolved config of the run. The sweep writes every key, so a key missing here
        means the run predates it: it takes the behaviour the run had (``config.migrate``),
        not today's default, or an old run's plain actor would be evaluated as a symmetric one."""
        return config.load(self.config, resolved=True)

    def write_config(self, cfg: config.Config) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        checkpoint.write_text_atomic(self.config, config.to_toml(cfg))

    @staticmethod
    def write_bytes(path: Path, data: bytes) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        checkpoint.write_bytes_atomic(path, data)

    @staticmethod
    def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        RunDir.write_bytes(path, buf.getvalue())

    @staticmethod
    def load_npz(path: Path) -> dict[str, np.ndarray] | None:
        """The arrays of ``path``, or None when it does not exist."""
        if not path.is_file():
            return None
        with np.load(path) as f:
            return {k: f[k] for k in f.files}

    @staticmethod
    def write_text(path: Path, text: str) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        checkpoint.write_text_atomic(path, text)

    @staticmethod
    def read_json(path: Path) -> Any:
        return json.loads(path.read_text(encoding="utf-8"))


def checkpoint_network(
    path: str | os.PathLike[str], meta: dict[str, Any]
) -> tuple[tuple[int, ...], bool]:
    """``(hidden, symmetric_actor)`` of the checkpoint at ``path`` (metadata ``meta``); a
    checkpoint that records its widths but not ``symmetric_actor`` predates that option."""
    if "hidden" in meta:
        return tuple(int(h) for h in meta["hidden"]), bool(meta.get("symmetric_actor", False))
    run = RunDir(Path(path).resolve().parents[2])  # RUN_DIR/checkpoints/mXX_sY/file
    if run.is_run():
        d = run.load_config().ddpg
        return tuple(d.hidden), d.symmetric_actor
    raise checkpoint.CheckpointError(
        f"checkpoint {path} records no network widths ('hidden') and has no run directory "
        "two levels up; build the function with jaxlc.policy.actor_fn(params, hidden)"
    )
