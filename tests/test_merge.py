"""One run per seed, merged, is the run of all the seeds: the same models in the same order."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxlc import config, sweep
from jaxlc.study import checkpoint, merge
from jaxlc.study.rundir import RunDir

from .conftest import SMOKE

GRID = ["grid.k=[1,2]", "grid.memory=[256]", "train.episodes=20"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[RunDir, RunDir]:
    """``(merged, together)``: seeds 0 and 1 trained apart then merged; and trained together."""
    root = tmp_path_factory.mktemp("merge")
    for s in (0, 1):
        cfg = config.load(SMOKE, [*GRID, f"train.seed={s}"])
        sweep.run_sweep(cfg, root / f"seed{s}", progress=False, devices=1)
    cfg = config.load(SMOKE, [*GRID, "train.seeds=2"])
    sweep.run_sweep(cfg, root / "together", progress=False, devices=1)
    assert merge.main([str(root / "merged"), str(root / "seed1"), str(root / "seed0")]) == 0
    return RunDir(root / "merged"), RunDir(root / "together")


def test_the_merged_run_is_the_run_of_all_seeds(runs) -> None:
    merged, together = runs
    assert merged.load_config() == together.load_config()
    a, b = merged.read_json(merged.summary_json), together.read_json(together.summary_json)
    keys = ("model", "cell", "seed", "label", "episodes")
    assert [{k: m[k] for k in keys} for m in a["models"]] == [
        {k: m[k] for k in keys} for m in b["models"]
    ]
    assert [m["seeds"] for m in a["merged_from"]] == [[1], [0]]
    mine = checkpoint.list_checkpoints(merged.root)
    theirs = checkpoint.list_checkpoints(together.root)
    assert [p.relative_to(merged.root) for p in mine] == [
        p.relative_to(together.root) for p in theirs
    ]
    for p, q in zip(mine, theirs, strict=True):
        (x, mx), (y, my) = checkpoint.load(p), checkpoint.load(q)
        assert {k: mx[k] for k in keys if k != "episodes"} == {
            k: my[k] for k in keys if k != "episodes"
        }
        # a model's numbers do not depend on the grid it ran in, up to float rounding that
        # the learning amplifies (as tests/test_devices.py allows between device layouts)
        for u, v in zip(jax.tree.leaves(x), jax.tree.leaves(y), strict=True):
            np.testing.assert_allclose(u, v, rtol=1e-3, atol=1e-4)
    ea, eb = merged.load_npz(merged.episodes), together.load_npz(together.episodes)
    assert ea.keys() == eb.keys()
    np.testing.assert_array_equal(ea["episodes"], eb["episodes"])
    assert ea["ret"].shape == eb["ret"].shape


def test_runs_that_differ_or_overlap_are_refused(runs, tmp_path, capsys) -> None:
    merged, together = runs
    # seeds 0-1 twice: they overlap
    assert merge.main([str(tmp_path / "a"), str(together.root), str(merged.root)]) == 2
    assert "distinct and without gaps" in capsys.readouterr().err
    other = tmp_path / "other"
    sweep.run_sweep(
        config.load(SMOKE, [*GRID, "train.seed=2", "ddpg.tau=0.01"]),
        other,
        progress=False,
        devices=1,
    )
    assert merge.main([str(tmp_path / "b"), str(together.root), str(other)]) == 2
    err = capsys.readouterr().err
    assert "differs from" in err and "ddpg.tau" in err


def test_configs_are_checked_before_any_run_is_read(tmp_path, capsys) -> None:
    """Run directories holding a config alone (no sweep): a seed gap and a differing key are
    refused in one line each, and seeds 0-1 beside seed 2 make one study of three seeds."""

    def run(name: str, *overrides: str) -> RunDir:
        rd = RunDir(tmp_path / name)
        rd.root.mkdir()
        rd.write_config(config.load(SMOKE, list(overrides)))
        return rd

    a, b = run("a", "train.seeds=2"), run("b", "train.seed=2")
    gap, other = run("gap", "train.seed=3"), run("other", "train.seed=2", "ddpg.tau=0.01")
    assert merge.merged_config([a, b]).train.seeds == 3
    assert merge.main([str(tmp_path / "m1"), str(a.root), str(gap.root)]) == 2
    assert "distinct and without gaps" in capsys.readouterr().err
    assert merge.main([str(tmp_path / "m2"), str(a.root), str(other.root)]) == 2
    err = capsys.readouterr().err
    assert "differs from" in err and "ddpg.tau" in err
    assert merge.main([str(tmp_path / "m3"), str(a.root), str(b.root)]) == 2
    assert "no summary.json" in capsys.readouterr().err
