"""``--tensorboard``: the event files hold the numbers of ``metrics/`` for a smoke run."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("tensorboardX", reason="optional: pip install -e '.[track]'")

from jaxlc import sweep  # noqa: E402
from jaxlc.learn import train  # noqa: E402
from jaxlc.sim.reward import SUCCESS  # noqa: E402
from jaxlc.study import tracking  # noqa: E402
from jaxlc.study.rundir import RunDir  # noqa: E402


@pytest.fixture(scope="module")
def tracked(tmp_path_factory, smoke_cfg):
    out, tb = tmp_path_factory.mktemp("run"), tmp_path_factory.mktemp("tb")
    summary = sweep.run_sweep(smoke_cfg, out, progress=False, tensorboard=tb)
    return out, tb, summary


def test_curves_hold_the_numbers_of_metrics(tracked, smoke_cfg):
    out, tb, summary = tracked
    grid, t = train.make_grid(smoke_cfg), smoke_cfg.train
    eps, steps = RunDir.load_npz(RunDir(out).episodes), RunDir.load_npz(RunDir(out).steps)
    chunks = steps["critic_loss"].shape[0] // t.chunk_steps
    per_model_chunk = t.chunk_steps * t.envs_per_model
    for i, meta in enumerate(summary["models"]):
        curves = tracking.read_scalars(tb / tracking.run_name(meta))
        # One point per chunk, at the model's env-steps.
        xs = [x for x, _ in curves["train/episodes"]]
        assert xs == [per_model_chunk * (c + 1) for c in range(chunks)]
        n = int(eps["episodes"][i])
        assert curves["train/episodes"][-1][1] == n
        ret, reason = eps["ret"][i, max(0, n - 100) : n], eps["reason"][i, max(0, n - 100) : n]
        np.testing.assert_allclose(curves["train/return_last100"][-1][1], ret.mean(), rtol=1e-6)
        ok = (reason == SUCCESS).mean()
        np.testing.assert_allclose(curves["train/success_last100"][-1][1], ok, rtol=1e-6)
        assert ok == pytest.approx(summary["models"][i]["success_rate_last"])
        # Losses: the mean over each chunk's steps of steps.npz.
        for name in ("critic_loss", "mean_q"):
            got = dict(curves[f"train/{name}"])
            for c in range(chunks):
                v = steps[name][c * t.chunk_steps : (c + 1) * t.chunk_steps, i]
                if np.isfinite(v).any():
                    want = np.nanmean(v)
                    np.testing.assert_allclose(got[per_model_chunk * (c + 1)], want, rtol=1e-5)
        assert len(curves["speed/env_steps_per_s"]) == chunks
        assert all(v > 0 for _, v in curves["speed/env_steps_per_s"])
    assert grid.size == len(summary["models"])


def test_the_tracked_run_trains_as_an_untracked_one(tracked, smoke_run):
    """Tracking only reads: the checkpoints are those of the fixture's untracked run."""
    out, _, _ = tracked
    ref, _ = smoke_run
    a = sorted(p.relative_to(out) for p in RunDir(out).checkpoints.rglob("*.msgpack"))
    b = sorted(p.relative_to(ref) for p in RunDir(ref).checkpoints.rglob("*.msgpack"))
    assert a == b and len(a) > 0
    for p in a:
        assert (out / p).read_bytes() == (ref / p).read_bytes(), p


class _Writer:
    """Stands in for a tensorboardX writer: the points ``chunk`` adds, by tag."""

    def __init__(self) -> None:
        self.points: dict[str, list[tuple[int, float]]] = {}

    def add_scalar(self, tag: str, value: float, step: int) -> None:
        self.points.setdefault(tag, []).append((step, value))


def test_a_chunk_writes_each_models_curves():
    """``TensorBoard.chunk`` on two models' logs, without a sweep or event files: each curve's
    point is the mean of the model's last 100 finished episodes, at the model's env-steps."""
    board = object.__new__(tracking.TensorBoard)
    board.writers = [_Writer(), _Writer()]
    ret = np.arange(2 * 150, dtype=np.float32).reshape(2, 150)
    reason = np.full((2, 150), SUCCESS)
    reason[1, 140:] = SUCCESS + 1
    metrics = {"critic_loss": np.array([[1.0, np.nan], [3.0, np.nan]]), "mean_q": np.ones((2, 2))}
    board.chunk(5000, {"ret": ret, "reason": reason}, np.array([150, 120]), metrics, 99.0)
    first, second = (w.points for w in board.writers)
    assert first["train/return_last100"] == [(5000, pytest.approx(ret[0, 50:].mean()))]
    assert second["train/return_last100"] == [(5000, pytest.approx(ret[1, 20:120].mean()))]
    assert first["train/success_last100"] == second["train/success_last100"] == [(5000, 1.0)]
    assert first["train/critic_loss"] == [(5000, 2.0)] and "train/critic_loss" not in second
    assert second["train/episodes"] == [(5000, 120)]
    assert first["speed/env_steps_per_s"] == [(5000, 99.0)]
    assert tracking.run_name({"model": 3, "seed": 1, "k": 2, "memory": 4000}) == "m03_s1_k2_D4000"
