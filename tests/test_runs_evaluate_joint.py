"""The runs of tests/test_runs_evaluate.py that use the wider config: lateral and longitudinal
control together, and a curved road trained by TD3. Each evaluates to a clean report (as there);
the joint run's checkpoint and export carry its two actions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jaxlc import export
from jaxlc.policy import load_policy
from jaxlc.sim.observation import MIRROR_SIGNS, OBS_DIM

from .test_runs_evaluate import check_run_evaluates, train_runs

# Each run: overrides of configs/smoke.toml (20 episodes: one checkpoint of each model).
RUNS = {
    # lateral and longitudinal control together, the headway term named
    "joint": [
        "grid.k=[2]",
        "grid.memory=[256]",
        "train.episodes=20",
        "env.longitudinal='policy'",
        "env.reward_terms=['r_s','r_e','r_d','r_gap']",
        "env.w_headway=2.0",
    ],
    "curved_td3": [
        "grid.k=[2]",
        "grid.memory=[512]",
        "train.episodes=20",
        "env.curvature=[-0.004,0.004]",
        "ddpg.learner='td3'",
    ],
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return train_runs(tmp_path_factory, RUNS)


@pytest.mark.parametrize("name", list(RUNS))
def test_every_run_evaluates_to_a_report(runs, name, capsys) -> None:
    check_run_evaluates(runs[name], name, RUNS[name], capsys)


def test_a_joint_run_loads_and_exports_its_two_actions(runs, tmp_path) -> None:
    """A run of ``env.longitudinal = "policy"``: its checkpoint acts with two entries, the
    lateral odd and the longitudinal even under the road's reflection, and its export says so."""
    run_dir = runs["joint"]
    path, _ = export.pick_checkpoint(run_dir)
    act, meta = load_policy(path)
    obs = np.random.default_rng(0).normal(size=(16, OBS_DIM)).astype(np.float32)
    a, a_m = np.asarray(act(obs)), np.asarray(act(obs * np.asarray(MIRROR_SIGNS, np.float32)))
    assert a.shape == (16, 2)
    np.testing.assert_array_equal(a_m, a * np.array([-1.0, 1.0], np.float32))
    out = tmp_path / "policy.stablehlo"
    assert export.main([str(run_dir), "--format", "stablehlo", "--out", str(out)]) == 0
    side = json.loads(out.with_name(out.name + ".json").read_text())["output"]
    assert side["shape"] == ["batch", 2]
    assert [e["mirror_sign"] for e in side["entries"]] == [-1.0, 1.0]
