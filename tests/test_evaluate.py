"""Evaluation: determinism, checkpoint round trip, outcome accounting, baselines, outputs, errors.

The worker's smoke sweep and one evaluation of it (module fixture) serve every test. Every
other evaluation here uses the same number of cases and policies per chunk, so the jitted
programs compile once.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxlc import config, evaluate
from jaxlc.evaluation import cases, engine, heldout, results, safety
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation.results import OUTCOMES
from jaxlc.learn.networks import make_networks
from jaxlc.policy import actor_fn
from jaxlc.report.report_text import FIGURES
from jaxlc.sim.controller import scripted_action
from jaxlc.sim.env import EnvParams, LaneChangeEnv
from jaxlc.study import checkpoint

from .conftest import HANG_GUARD_S, SMOKE

CASES, CHUNK = 60, 4  # 60 cases: ~40 lane changes, enough for the success-rate thresholds
LANE_CHANGES = 40  # held-out lane changes per final checkpoint (1000 by default)


@pytest.fixture(scope="module")
def run(
    smoke_run, smoke_cfg: config.Config, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, config.Config, dict]:
    """The worker's smoke sweep (checkpoints at 20 and 40 episodes), copied so that the
    evaluation's files stay this module's, evaluated by the CLI."""
    run_dir, _ = smoke_run
    out = tmp_path_factory.mktemp("smoke") / "run"
    shutil.copytree(run_dir, out)
    args = [str(out), "--cases", str(CASES), "--chunk", str(CHUNK)]
    assert evaluate.main([*args, "--lane-changes", str(LANE_CHANGES)]) == 0
    return out, smoke_cfg, json.loads((out / "eval" / "eval.json").read_text())


def _evaluate(cfg: config.Config, actors: list, ks: list[int]) -> list[dict]:
    out, _, _ = cases.evaluate_policies(cfg, actors, ks, cases=CASES, chunk=CHUNK)
    return results.summarise(out, cfg.env.dt), out


def test_default_episodes_are_the_papers() -> None:
    paper = [100, *range(400, 5000, 400), 5000]
    assert evaluate.default_episodes(100, 5000) == paper
    assert evaluate.default_episodes(20, 40) == [20, 40]


def test_outcome_counts_add_up_to_the_cases(run) -> None:
    run_dir, _, result = run
    rows = result["rows"]
    assert rows[0]["model"] is None  # the scripted baseline row
    n_ckpt = len(checkpoint.list_checkpoints(run_dir))
    assert len(rows) == 1 + n_ckpt  # checkpoints 20, 40: both default episodes
    for r in rows:
        assert r["cases"] == CASES
        assert sum(r[o] for o in OUTCOMES) == CASES
        assert r["performed"] == result["performed"]  # the same cases for every policy
        assert r["success"] + r["out_of_bounds"] + r["timeout"] <= r["performed"]
    per_case = np.load(run_dir / "eval" / "cases.npz")
    assert per_case["reason"].shape == (len(rows), CASES)
    assert set(np.unique(per_case["reason"])) <= set(range(len(OUTCOMES)))
    csv_lines = (run_dir / "eval" / "eval.csv").read_text().strip().splitlines()
    assert len(csv_lines) == 1 + len(rows)


def test_evaluating_a_checkpoint_twice_is_identical(run) -> None:
    run_dir, cfg, result = run
    path = checkpoint.list_checkpoints(run_dir)[-1]
    params, meta = checkpoint.load(path)
    actors, ks = [params, None, params, params], [meta["k"], 1, meta["k"], meta["k"]]
    rows_a, out_a = _evaluate(cfg, actors, ks)
    rows_b, out_b = _evaluate(cfg, actors, ks)
    for name in out_a:
        np.testing.assert_array_equal(out_a[name], out_b[name], err_msg=name)
    assert rows_a[0] == rows_a[2] == rows_a[3]  # its place in the batch changes nothing
    # ...nor does the batch it ran in: the CLI evaluation put it beside other checkpoints.
    saved = next(r for r in result["rows"] if r["checkpoint"] == str(path.relative_to(run_dir)))
    for key in (*OUTCOMES, "performed", "success_rate", "avg_return"):
        assert saved[key] == pytest.approx(rows_a[0][key], rel=1e-6), key


def test_checkpoint_file_gives_the_saved_params_actions(run, tmp_path: Path) -> None:
    _, cfg, _ = run
    # Non-trivial params (a fresh actor's small last layer would act ~0 everywhere).
    fresh = cases.init_actor(cfg, jax.random.PRNGKey(7))
    leaves, tree = jax.tree.flatten(fresh)
    keys = jax.random.split(jax.random.PRNGKey(8), len(leaves))
    params = jax.tree.unflatten(
        tree, [0.5 * jax.random.normal(k, x.shape) for k, x in zip(keys, leaves, strict=True)]
    )
    path = checkpoint.save(tmp_path / "ck.msgpack", jax.device_get(params), {"k": 2, "model": 0})
    loaded, meta = checkpoint.load(path)

    obs = jax.random.normal(jax.random.PRNGKey(9), (256, 14))
    want = np.asarray(actor_fn(params, cfg.ddpg.hidden)(obs))
    np.testing.assert_array_equal(np.asarray(actor_fn(loaded, cfg.ddpg.hidden)(obs)), want)
    assert np.std(want) > 0.1  # the comparison is not between two constants

    _, out = _evaluate(cfg, [loaded, params, None, loaded], [meta["k"], 2, 1, meta["k"]])
    for name in out:
        np.testing.assert_array_equal(out[name][0], out[name][1], err_msg=name)


def test_scripted_succeeds_where_a_random_actor_fails(run) -> None:
    _, cfg, _ = run
    random_actor = cases.init_actor(cfg, jax.random.PRNGKey(1))
    rows, _ = _evaluate(cfg, [None, random_actor, None, random_actor], [1, 1, 1, 1])
    scripted, rand = rows[0], rows[1]
    assert scripted["performed"] >= 20  # enough lane changes for the rates to mean something
    assert scripted["success_rate"] >= 0.95
    assert rand["success_rate"] < 0.5
    assert scripted["avg_return"] > rand["avg_return"]
    # The baseline drives like a human: a lane change of a few seconds, little overshoot.
    assert 3.0 <= scripted["duration_s"] <= 8.0
    assert scripted["overshoot_m"] < 0.5


def test_a_policy_given_as_a_function_meets_the_same_cases(run) -> None:
    """``evaluate_act`` (any learner's policy as a function) sees the cases every checkpoint
    sees: the scripted controller through it equals the scripted baseline row."""
    _, cfg, _ = run
    p = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    got = cases.evaluate_act(cfg, lambda obs: scripted_action(obs, p), cases=CASES)
    _, want = _evaluate(cfg, [None], [1])
    for name in want:
        np.testing.assert_array_equal(got[name][0], want[name][0], err_msg=name)


def test_every_figure_and_the_report_are_written(run) -> None:
    run_dir, _, _ = run
    for name, _ in FIGURES:
        path = run_dir / "figures" / name
        assert path.is_file() and path.stat().st_size > 0, name
    report = (run_dir / "report.md").read_text()
    assert "scripted controller" in report and "Best model" in report
    for name, _ in FIGURES:
        assert f"figures/{name}" in report


def test_heldout_rows_count_every_lane_change_and_attribute_every_collision(run) -> None:
    """Final checkpoints and the scripted controller on exactly LANE_CHANGES held-out lane
    changes each: outcome counts add up, intervals hold the rate, every collision has a row
    with the vehicle hit, and the report carries the section and claim (d)."""
    run_dir, _, result = run
    doc = json.loads((run_dir / "eval" / "heldout.json").read_text())
    finals = {r["model"] for r in result["rows"] if r["model"] is not None}
    assert [r["model"] for r in doc["rows"]] == [None, *sorted(finals)]
    assert doc["lane_changes"] == LANE_CHANGES and doc["cases"] > LANE_CHANGES
    for r in doc["rows"]:
        assert r["lane_changes"] == LANE_CHANGES
        assert sum(r[e] for e in heldout.ENDS) == LANE_CHANGES
        assert r["success_lo"] <= r["success_rate"] <= r["success_hi"]
        assert r["failure_bound"] >= 1 - r["success_rate"]  # an upper bound on the failures
        assert 0.0 <= r["norm_all"] <= r["norm_peak_lat_acc"] <= 1.0
    hits = sum(r["collision"] for r in doc["rows"])
    assert len(doc["collisions"]) == hits
    assert all(h["partner"] in safety.PARTNERS[1:] for h in doc["collisions"])
    csv_rows = (run_dir / "eval" / "collisions.csv").read_text().strip().splitlines()
    assert len(csv_rows) == 1 + hits
    assert len(doc["cells"]) == len({r["cell"] for r in result["rows"] if r["model"] is not None})
    per_case = np.load(run_dir / "eval" / "heldout_cases.npz")
    assert per_case["reason"].shape == (len(doc["rows"]), doc["cases"])
    assert per_case["performed"].sum() == LANE_CHANGES
    report = (run_dir / "report.md").read_text()
    assert "## Held-out lane changes" in report and doc["claim_d"]["figures"] in report


def test_manoeuvres_keep_their_final_state(run) -> None:
    run_dir, cfg, result = run
    per_case = np.load(run_dir / "eval" / "cases.npz")
    reason = per_case["reason"]  # (policies, cases); "performed" is the cases' (the same for all)
    performed = np.broadcast_to(per_case["performed"], reason.shape)
    final = {n: per_case[n] for n in ("final_offset", "final_psi", "final_omega")}
    for name, v in final.items():
        assert np.isfinite(v[performed]).all() and np.isnan(v[~performed]).all(), name
    # The last step decided the outcome: successes end inside the success box, timeouts
    # outside it.
    e = cfg.env
    inside = (
        (np.abs(final["final_offset"]) <= e.success_offset)
        & (np.abs(final["final_psi"]) <= e.success_heading)
        & (np.abs(final["final_omega"]) <= e.success_yaw_rate)
    )
    assert inside[reason == OUTCOMES.index("success")].all()
    assert not inside[reason == OUTCOMES.index("timeout")].any()
    for r in result["rows"]:
        for key in ("timeout_offset_m", "timeout_heading", "timeout_yaw_rate"):
            assert (r[key] is not None and r[key] >= 0) if r["timeout"] else r[key] is None, key
    assert result["success_box"]["offset_m"] == e.success_offset


def test_a_measure_declared_once_reaches_heldout_csv_and_the_report(run, tmp_path: Path) -> None:
    """One ``measures.register`` call, nothing else: the measure is folded over every
    manoeuvre (its reducer, a max here), kept per case in ``heldout_cases.npz``, summarised
    per model in ``heldout.csv`` and ``heldout.json`` (the mean over the successful lane
    changes) and shown in the report's held-out table; every built-in column stays as it was."""
    from jaxlc.evaluation import measures
    from jaxlc.evaluation.protocol import evaluate_heldout
    from jaxlc.report import report

    run_dir, cfg, _ = run
    out = tmp_path / "run"
    shutil.copytree(run_dir, out)
    top = measures.Measure("top_speed", "max", lambda s, p: s.state.ego.v, heldout="mean")
    measures.register(top)
    try:
        doc = evaluate_heldout(out, lane_changes=LANE_CHANGES, chunk=CHUNK)
        report.write_report(out)
    finally:
        measures.unregister("top_speed")
    header = (out / "eval" / "heldout.csv").read_text().splitlines()[0].split(",")
    assert header == [*heldout.fields(), "top_speed"]  # fields(): the built-ins again
    assert header[:-1] == (run_dir / "eval" / "heldout.csv").read_text().splitlines()[0].split(",")
    per_case = np.load(out / "eval" / "heldout_cases.npz")
    before = np.load(run_dir / "eval" / "heldout_cases.npz")
    # the outcome's columns, the new one after the built-ins, then the ids and case info
    assert [f for f in per_case.files if f != "top_speed"] == before.files
    last = measures.BUILTIN[-1].name  # the registered measures follow every built-in one
    assert per_case.files.index("top_speed") == before.files.index(last) + 1
    for name in ("reason", "steps", "min_ttc", "partner", "tilt"):  # the built-ins unchanged
        np.testing.assert_array_equal(per_case[name], before[name], err_msg=name)
    top_v, perf = per_case["top_speed"], per_case["performed"]
    assert np.all(top_v[:, perf] > 0.0) and np.all(top_v[:, ~perf] == 0.0)  # fill: no steps
    success = per_case["reason"] == OUTCOMES.index("success")
    assert doc["measures"] == ["top_speed"]
    for p, row in enumerate(doc["rows"]):
        ok = perf & success[p]
        want = float(np.mean(top_v[p][ok])) if ok.any() else math.nan  # undefined: no success
        assert row["top_speed"] == pytest.approx(want, nan_ok=True), row["label"]
    assert doc["rows"][0]["model"] is None and success[0][perf].any()  # the scripted succeeds
    text = (out / "report.md").read_text()
    assert " top_speed |" in text
    names = [m.name for m in measures.of(EnvParams.from_config(cfg.env))]
    assert "top_speed" not in names and not measures.registered()  # unregistered again


def test_seed_statistics_are_written_and_say_one_seed_is_not_enough(run) -> None:
    run_dir, _, result = run
    doc = json.loads((run_dir / "eval" / "cells.json").read_text())
    assert "intervals need >= 2 seeds" in doc["note"]
    n_cells = len({r["cell"] for r in result["rows"] if r["model"] is not None})
    assert len(doc["final"]) == n_cells and len(doc["improvement"]) == n_cells * (n_cells - 1)
    for name in ("cells.csv", "improvement.csv"):
        assert (run_dir / "eval" / name).is_file(), name
    report = (run_dir / "report.md").read_text()
    assert "intervals need >= 2 seeds" in report
    # the smoke grid has none of the paper's cells: every claim is named, none decided
    claims = [x for x in report.splitlines() if x.startswith("| (")]
    assert len(claims) == 5 and all("**n/a**" in x or "undecided at 1 seed" in x for x in claims)


@pytest.mark.slow
@pytest.mark.parametrize("with_config", [False, True])
def test_dir_without_checkpoints_exits_2_with_one_line(tmp_path: Path, with_config: bool) -> None:
    if with_config:  # a run that stopped before its first checkpoint
        (tmp_path / "config.toml").write_text(SMOKE.read_text())
        (tmp_path / "checkpoints" / "m00_s0").mkdir(parents=True)
    proc = subprocess.run(
        [sys.executable, "-m", "jaxlc.evaluate", str(tmp_path), "--no-figures"],
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: no checkpoints in "), proc.stderr
    assert not (tmp_path / "eval").exists()


def test_corrupt_checkpoint_exits_2_with_one_line(run, tmp_path: Path, capsys) -> None:
    run_dir, _, _ = run
    (tmp_path / "config.toml").write_text((run_dir / "config.toml").read_text())
    src = checkpoint.list_checkpoints(run_dir)[0]
    dst = tmp_path / "checkpoints" / src.parent.name / src.name
    dst.parent.mkdir(parents=True)
    dst.write_bytes(src.read_bytes()[:50])  # truncated params, intact metadata
    dst.with_suffix(".json").write_text(src.with_suffix(".json").read_text())
    capsys.readouterr()
    assert evaluate.main([str(tmp_path), "--cases", str(CASES), "--chunk", str(CHUNK)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "corrupt" in err[0]


def test_the_protocol_comes_from_the_runs_eval_table_and_flags_override_it(
    tmp_path: Path, capsys
) -> None:
    cfg = config.load(SMOKE, ["eval.cases=7", "eval.lane_changes=0", "eval.chunk=3"])
    (tmp_path / "config.toml").write_text(config.to_toml(cfg))
    assert cfg.hash() == config.load(SMOKE).hash()  # evaluating otherwise is the same run
    _, ev = evaluate._protocol(evaluate.parse_args([str(tmp_path)]))
    assert (ev.cases, ev.lane_changes, ev.chunk, ev.max_steps) == (7, 0, 3, 1500)
    _, ev = evaluate._protocol(evaluate.parse_args([str(tmp_path), "--cases", "5"]))
    assert (ev.cases, ev.chunk) == (5, 3)
    # a bad value is refused as the config refuses it, naming the key; nothing runs
    assert evaluate.main([str(tmp_path), "--chunk", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'eval.chunk'" in err[0] and ">= 1" in err[0], err
    assert not (tmp_path / "eval").exists()


@pytest.mark.slow
def test_a_batch_of_case_starts_is_each_case_started_alone() -> None:
    """``make_start_cases`` steps the batch together, then finishes its slowest cases in
    blocks of ``n // SPILL``: every case's start equals the plain vmapped start bit for bit,
    and the batch's approach lengths differ (so both stages ran)."""
    base = EnvParams.from_config(config.load(SMOKE).env)
    n = engine.SPILL_MIN_BATCH
    keys = streams.stream(0, streams.HELDOUT, range(n))
    plain = jax.jit(jax.vmap(engine.make_start_case(base, 600)))(keys)
    batched = jax.jit(cases.make_start_cases(base, 600))(keys)
    for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(batched), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    steps = np.asarray(plain.state.time)
    assert steps.max() > np.sort(steps)[-(n // engine.SPILL) - 1], steps


@pytest.mark.slow
def test_a_rollout_of_a_batch_is_each_case_rolled_out_alone(monkeypatch) -> None:
    """``make_rollout`` runs most of the batch together, then finishes its slowest cases in
    blocks of ``n // SPILL``: every policy's outcome and trace on every case equal those of
    the plain loop over the whole batch bit for bit, and the manoeuvres' lengths differ (so
    both stages ran)."""
    cfg = config.load(SMOKE)
    base = EnvParams.from_config(cfg.env)
    n = engine.SPILL_MIN_BATCH
    cs = jax.jit(cases.make_start_cases(base, 600))(streams.stream(0, streams.HELDOUT, range(n)))
    actor = cases.init_actor(cfg, jax.random.PRNGKey(1))
    pol = cases.Policies(
        actor=jax.tree.map(lambda a: np.stack([a, a]), actor),
        k=np.asarray([1, 2], np.int32),
        scripted=np.asarray([True, False]),
    )
    traced = np.asarray(cases.pick_traced(cs, 3))
    apply = make_networks(cfg.ddpg, 1)[0].apply
    batched = jax.jit(cases.make_rollout(base, apply, 600))(pol, cs, traced)
    monkeypatch.setattr(engine, "SPILL_MIN_BATCH", n + 1)  # the plain loop (engine.spill's)
    plain = jax.jit(cases.make_rollout(base, apply, 600))(pol, cs, traced)
    for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(batched), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    steps = np.asarray(plain[0]["steps"]).max(axis=0)  # (cases,) the longest of the policies'
    assert np.asarray(cs.performed).sum() > n // engine.SPILL
    assert steps.max() > np.sort(steps)[-(n // engine.SPILL) - 1], steps


@pytest.mark.slow
@pytest.mark.parametrize("traffic", [[], ["env.mobil=true", "env.braking=true"]])
def test_the_traffic_only_warm_up_gives_the_full_warm_ups_traffic(traffic) -> None:
    """``reset(..., traffic_only=True)`` (the validation's cases) warms the same traffic as
    the full step, to float32 rounding, with lane changes and braking events too, and leaves
    the ego at its reset values (WAIT, at rest)."""
    over = [*traffic, "env.braking_rate=3600", "env.mobil_rate=2"] if traffic else []
    base = EnvParams.from_config(config.load(SMOKE, over).env)
    env = LaneChangeEnv()
    keys = streams.stream(1, streams.HELDOUT, range(128))
    full = jax.jit(jax.vmap(lambda k: env.reset(k, base)[1]))(keys)
    fast = jax.jit(jax.vmap(lambda k: env.reset(k, base, traffic_only=True)[1]))(keys)
    assert np.asarray(full.traffic.active).sum() > 128 * 3  # a filled road
    if traffic:
        assert np.asarray(full.traffic.lc_time < 1e3).any()  # some lane changes happened
    leaves = jax.tree_util.tree_leaves_with_path(full.traffic)
    for (path, a), b in zip(leaves, jax.tree.leaves(fast.traffic), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype.kind == "f":
            np.testing.assert_allclose(b, a, rtol=1e-6, err_msg=jax.tree_util.keystr(path))
        else:
            np.testing.assert_array_equal(b, a, err_msg=jax.tree_util.keystr(path))
    assert (np.asarray(fast.ego.phase) == 0).all()
    assert (np.asarray(fast.ego.x) == 0).all() and (np.asarray(fast.ego.v) == 0).all()
    assert (np.asarray(full.ego.x) > 0).any()  # the full warm-up lets the ego coast
