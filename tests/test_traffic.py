"""The traffic that cuts in and brakes (env.mobil, env.braking): physical properties over a
long run at the highest configured rates, MOBIL on hand-built cases, the rates as traced
values, the config's checks, and the held-out evaluation in another traffic."""

import dataclasses
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

import jaxlc
from jaxlc import config
from jaxlc.evaluation import heldout
from jaxlc.sim import leaders, mobil
from jaxlc.sim.env import EnvParams
from jaxlc.sim.state import TrafficDraws

from .conftest import changed_env_keys

HAZARDS = ("env.mobil=true", "env.braking=true")
# A harsher traffic than SPEC's: the held-out run below and the suite's setting of that name,
# at one count of lane changes, are one config, so the second reuses the first's programs.
HARSH = (*HAZARDS, "env.braking_rate=600.0", "env.mobil_politeness=0.0")
HARSH_LANE_CHANGES = 12


@pytest.fixture(scope="module")
def long_run():
    """256 envs x 400 steps (102,400 env-steps) at the ranges' highest rates."""
    from benchmarks import traffic_properties as bench

    return bench.check(256, 400, bench.HIGHEST, chunk=400)


def test_the_traffic_stays_physical_at_the_highest_rates(long_run):
    t = long_run
    assert t["env_steps"] >= 100_000
    assert t["overlaps"] == 0, "two non-ego bodies overlap"
    assert t["negative_speeds"] == 0
    assert t["off_road"] == 0
    assert t["unsafe_starts"] == 0, "a lane change started against MOBIL's safety criterion"
    # exercised: the run holds many lane changes and braking events
    assert t["lc_started"] > 1000 and t["brake_started"] > 1000


@pytest.mark.parametrize("name", ["lane_change", "braking"])
def test_event_rates_match_their_configured_values(long_run, name):
    lo, hi = long_run[f"{name}_interval"]  # 99.9% Clopper-Pearson of the observed rate
    assert lo <= long_run[f"{name}_expected"] <= hi


@functools.cache
def _hazard_reset():
    """The hazard traffic's ``reset``, compiled once for the file's hand-built states."""
    return jax.jit(jaxlc.make(config.load(overrides=HAZARDS))[0].reset)


def _traffic(p: EnvParams, vehicles: list[tuple[int, float, float]]):
    """A state whose traffic holds ``vehicles`` (lane, x, v), one per row slot in order,
    every v0 33 m/s, and no ego on the road."""
    _, s = _hazard_reset()(jax.random.PRNGKey(0), p.replace(warmup_steps=0))
    tr = s.traffic
    x, v, act, lane = (np.zeros(tr.x.shape, t) for t in (np.float32, np.float32, bool, np.int32))
    lane[:] = np.arange(p.lanes)[:, None]
    for i, (ln, xi, vi) in enumerate(vehicles):
        x[ln, i], v[ln, i], act[ln, i] = xi, vi, True
    tr = tr.replace(
        x=jnp.asarray(x),
        v=jnp.asarray(v),
        v0=jnp.full(tr.x.shape, 33.0),
        active=jnp.asarray(act),
        lane=jnp.asarray(lane),
        lane_from=jnp.asarray(lane),
    )
    return s.replace(traffic=tr)


def _decide(p: EnvParams, s):
    a = leaders.around(s.traffic, s.ego, p, jnp.ones(p.lanes))
    u = TrafficDraws(*jnp.zeros((5,) + s.traffic.x.shape))  # every driver acts at once
    return mobil.decide(s.traffic, a, u, p)


@pytest.mark.slow
def test_mobil_leaves_a_slow_leader_for_a_free_lane_only_when_it_is_safe():
    polite = jaxlc.make(config.load(overrides=HAZARDS))[1]
    p = polite.replace(mobil_politeness=0.0)  # selfish drivers
    # lane 0: a car at 25 m/s, 20 m behind a truck at 10 m/s; lane 1 empty around them
    free = _decide(p, _traffic(p, [(0, 300.0, 10.0), (0, 275.0, 25.0)]))
    assert bool(free.start[0, 1]) and int(free.to[0, 1]) == 1  # moves left, to lane 1
    assert bool(free.weighed[0, 0]) and not bool(free.allowed[0, 0])  # the truck gains nothing
    # with politeness 0.2 the truck moves over for the car (its gain weighs), and of the
    # two starting into one spot on one step only the truck goes
    both = _decide(polite, _traffic(p, [(0, 300.0, 10.0), (0, 275.0, 25.0)]))
    assert bool(both.allowed[0, 0]) and bool(both.allowed[0, 1])
    assert bool(both.start[0, 0]) and not bool(both.start[0, 1])
    # the same with a fast car 8 m behind in lane 1: it would brake harder than b_safe
    blocked = _decide(p, _traffic(p, [(0, 300.0, 10.0), (0, 275.0, 25.0), (1, 262.0, 30.0)]))
    assert not bool(blocked.start[0, 1])


@pytest.mark.slow
def test_two_drivers_do_not_start_into_one_spot_on_one_step():
    p = jaxlc.make(config.load(overrides=HAZARDS))[1]
    # lanes 0 and 2 each hold a car behind a slow truck, side by side: both want lane 1
    s = _traffic(p, [(0, 300.0, 10.0), (0, 275.0, 25.0), (2, 300.0, 10.0), (2, 275.0, 25.0)])
    d = _decide(p, s)
    assert bool(d.allowed[0, 1]) and bool(d.allowed[2, 3])
    assert int(d.start.sum()) == 1


@pytest.mark.slow
def test_of_the_drivers_acting_on_one_step_the_first_deciders_weigh_a_change():
    p = jaxlc.make(config.load(overrides=HAZARDS))[1].replace(mobil_deciders=5)
    # twelve cars 30 m apart at 10 m/s in lane 0, lane 1 empty: each gains by moving left (the
    # first for its follower), none within another's safe distance (22 m); every driver acts
    cars = [(0, 500.0 - 30.0 * i, 10.0) for i in range(12)]
    d = jax.device_get(_decide(p, _traffic(p, cars)))
    assert d.eligible.sum() == 12
    assert list(np.flatnonzero(d.weighed)) == [0, 1, 2, 3, 4]  # slot order, first five
    assert list(np.flatnonzero(d.start)) == [0, 1, 2, 3, 4]
    assert (d.to[0, :5] == 1).all() and (d.to.reshape(-1)[5:] == -1).all()
    # with room for all, every driver starts
    d = jax.device_get(_decide(p.replace(mobil_deciders=48), _traffic(p, cars)))
    assert list(np.flatnonzero(d.start)) == list(range(12))


@pytest.mark.parametrize("rate", [0.5, 2.0, 10.0])
def test_the_deciders_cover_every_driver_acting_but_one_step_in_a_million(rate):
    p = jaxlc.make(config.load(overrides=(*HAZARDS, f"env.mobil_rate={rate}")))[1]
    n, q = p.lanes * p.slots_per_lane, -np.expm1(-rate * p.dt)
    k = p.mobil_deciders
    assert scipy.stats.binom.sf(k, n, q) <= 1e-6 < scipy.stats.binom.sf(k - 1, n, q)


@pytest.mark.slow
def test_the_traffic_draws_are_uniform_and_independent():
    p = jaxlc.make(config.load(overrides=HAZARDS))[1]
    keys = jax.random.split(jax.random.PRNGKey(11), 4096)
    u = jax.vmap(lambda k: TrafficDraws.draw(k, p.lanes, p.slots_per_lane))(keys)
    u = np.stack([np.asarray(a) for a in u], axis=1).reshape(4096, -1)  # (keys, numbers)
    assert ((u >= 0.0) & (u < 1.0)).all()
    for per_number in (u[:, 0], u[:, 7], u[:, -1], u.reshape(-1)):  # across keys; all at once
        assert scipy.stats.kstest(per_number, "uniform").pvalue > 1e-4
    # neighbouring numbers of one step and one number of neighbouring keys: uncorrelated
    r_next = np.corrcoef(u[:, :-1].reshape(-1), u[:, 1:].reshape(-1))[0, 1]
    r_keys = np.corrcoef(u[:-1].reshape(-1), u[1:].reshape(-1))[0, 1]
    assert abs(r_next) < 0.01 and abs(r_keys) < 0.01
    # the step's key alone decides them: the same key, the same numbers
    again = TrafficDraws.draw(keys[3], p.lanes, p.slots_per_lane)
    assert np.array_equal(np.stack([np.asarray(a) for a in again]).reshape(-1), u[3])


def _pairwise_around(x, occ):
    """The definition ``leaders.around`` computes by sorting, pair by pair: per lane, the
    nearest vehicle counting in it ahead (larger x, ties by larger index) and behind."""
    idx = np.arange(x.size)
    ahead = (x[None, :] > x[:, None]) | ((x[None, :] == x[:, None]) & (idx[None] > idx[:, None]))
    behind = ~ahead & (idx[None] != idx[:, None])
    front = np.where(ahead[None] & occ[:, None, :], x[None, None, :], np.inf)
    back = np.where(behind[None] & occ[:, None, :], x[None, None, :], -np.inf)
    return front.argmin(-1), np.isfinite(front.min(-1)), back.argmax(-1), np.isfinite(back.max(-1))


def test_position_keys_keep_the_order_and_never_read_as_none_even_past_the_road():
    # 64 bodies: the index fills the key's low bits; the last two far past the road's end,
    # where the position's level is clipped (in float32, whose rounding of the top level
    # would overflow int32) and the key must still sort last and stay below "no lead"
    x = jnp.concatenate([jnp.linspace(-300.0, 900.0, 62), jnp.array([5e3, 1e6])])
    keys = np.asarray(leaders._keys(x.astype(jnp.float32), jnp.float32(600.0)))
    assert (keys >= 0).all() and keys.max() < np.iinfo(np.int32).max
    assert (np.argsort(keys, kind="stable") == np.arange(64)).all()


def test_leaders_by_keys_equal_every_pair_compared_in_float():
    p = jaxlc.make(config.load(overrides=HAZARDS))[1]
    rng = np.random.default_rng(5)
    cases = []
    for _ in range(40):  # random traffics: any lane, a third of them mid lane change
        lanes = [
            (int(rng.integers(p.lanes)), float(rng.uniform(0, 600)), 20.0)
            for _ in range(p.slots_per_lane)
        ]
        s = _traffic(p, lanes)
        tr = s.traffic
        shape = tr.x.shape
        frm = np.clip(np.asarray(tr.lane) + rng.choice([-1, 1], shape), 0, p.lanes - 1)
        mid = rng.uniform(size=shape) < 0.33
        tr = tr.replace(
            lane_from=jnp.asarray(np.where(mid, frm, np.asarray(tr.lane)), jnp.int32),
            lc_time=jnp.asarray(np.where(mid, 1.0, 1e4), jnp.float32),
            lc_dur=jnp.full(shape, 4.0),
        )
        eg = s.ego.replace(x=jnp.float32(rng.uniform(0, 600)), phase=jnp.int32(1))
        cases.append((tr, eg))

    def run(tr, eg):
        a = leaders.around(tr, eg, p, jnp.ones(p.lanes))
        return a, leaders.lags(a, jnp.arange(a.x.shape[0]))

    run = jax.jit(run)
    checked = 0
    for tr, eg in cases:
        a, (a_lag, a_has_lag) = jax.device_get(run(tr, eg))
        lead, has_lead, lag, has_lag = _pairwise_around(np.asarray(a.x), np.asarray(a.occ))
        assert (a.has_lead == has_lead).all() and (a_has_lag == has_lag).all()
        assert (a.lead[has_lead] == lead[has_lead]).all()
        assert (a_lag[has_lag] == lag[has_lag]).all()
        checked += int(has_lead.sum() + has_lag.sum())
    assert checked > 1000  # exercised: many leaders and followers, straddlers among them


def test_the_nearest_key_is_found_when_every_body_or_none_counts_in_a_lane():
    # The search takes a key's distance as uint32: a lane every body counts in (no key
    # standing for "none" among them), an empty one, and the first and last keys as subjects.
    rng = np.random.default_rng(7)
    key = np.sort(rng.choice(2**30, 49, replace=False)).astype(np.int32) * 2
    occ = np.stack([np.ones(49, bool), np.zeros(49, bool), rng.uniform(size=49) < 0.5])
    find = jax.jit(leaders._nearest, static_argnames="ahead")
    for ahead, none in ((True, np.iinfo(np.int32).max), (False, -1)):
        got = np.asarray(find(jnp.asarray(key), jnp.asarray(occ), jnp.asarray(key), ahead=ahead))
        for lane in range(3):
            for i, k in enumerate(key):
                side = key[occ[lane] & ((key > k) if ahead else (key < k))]
                want = (side.min() if ahead else side.max()) if side.size else none
                assert got[lane, i] == want, (ahead, lane, i)


@pytest.mark.slow
def test_rates_are_traced_one_program_runs_a_batch_of_traffics():
    env, p = jaxlc.make(config.load(overrides=(*HAZARDS, "env.warmup_time=20.0")))
    rates = jnp.array([0.0, 3600.0])  # braking events per vehicle-hour
    params = jax.tree.map(lambda a: jnp.stack([a, a]), p).replace(braking_rate=rates / 3600.0)
    keys = jax.random.split(jax.random.PRNGKey(3), 2)
    _, s = jax.vmap(env.reset)(keys, params)
    braking = np.asarray(jnp.sum(s.traffic.brake_left > 0.0, axis=(1, 2)))
    assert braking[0] == 0 and braking[1] > 0


@pytest.mark.slow
def test_paper_traffic_has_no_hazard_state():
    _, s = jaxlc.make()[0].reset(jax.random.PRNGKey(0), jaxlc.make()[1])
    tr = s.traffic
    assert tr.lane is None and tr.lc_time is None and tr.brake_left is None
    assert not config.load(config.PAPER_CONFIG).env.mobil
    assert not config.load(config.PAPER_CONFIG).env.braking


@pytest.mark.parametrize(
    "override, key",
    [
        ("env.braking_decel_max=9.5", "env.braking_decel_max"),
        ("env.mobil_rate=0", "env.mobil_rate"),
        ("env.lane_change_time_min=7.0", "env.lane_change_time_min"),
        ("env.braking_rate=-1", "env.braking_rate"),
    ],
)
def test_a_bad_traffic_value_names_its_key(override, key):
    with pytest.raises(config.ConfigError, match=key.replace(".", r"\.")):
        heldout.in_traffic(config.load(), [override])


def test_traffic_overrides_take_env_keys_only():
    cfg = heldout.in_traffic(config.load(), HAZARDS)
    assert cfg.env.mobil and cfg.env.braking and cfg.ddpg == config.load().ddpg
    assert "MOBIL" in heldout.traffic_of(cfg.env) and "braking" in heldout.traffic_of(cfg.env)
    with pytest.raises(config.ConfigError, match="only \\[env\\] keys"):
        heldout.in_traffic(config.load(), ["ddpg.gamma=0.5"])


def test_heldout_lane_changes_in_another_traffic(smoke_run):
    from jaxlc.evaluate import main

    run_dir, _ = smoke_run
    argv = [str(run_dir), "--heldout-only", "--lane-changes", str(HARSH_LANE_CHANGES)]
    argv += ["--tag", "hazards"]
    assert main([*argv, "--traffic", "env.mobil=true", "env.braking_rate=-1"]) == 2
    assert main([*argv, "--traffic", *HARSH]) == 0
    doc = json.loads((run_dir / "eval" / "heldout_hazards" / "heldout.json").read_text())
    assert doc["traffic_overrides"] == list(HARSH)
    assert doc["traffic"].startswith("traffic with MOBIL lane changes")
    assert doc["lane_changes"] >= HARSH_LANE_CHANGES
    for row in doc["rows"]:
        assert 0 <= row["met_cut_in"] <= row["lane_changes"] and row["cut_ins"] >= row["met_cut_in"]


def test_every_config_file_spells_the_traffic_keys_off_but_reactive():
    for name in ("default.toml", "paper.toml", "joint.toml", "joint_assist.toml"):
        env = config.load(config.CONFIG_DIR / name).env
        assert not env.mobil and not env.braking, name
    # reactive.toml: today's default trained in the traffic that cuts in and brakes
    assert changed_env_keys("reactive.toml", config.load()) == {"mobil", "braking"}
    reactive = config.load(config.CONFIG_DIR / "reactive.toml")
    assert dataclasses.replace(reactive, env=config.load().env) == config.load()


# Every key of params.RANGED as a range at once: stop-and-go to free flow, no MOBIL or braking
# to far past SPEC's rates, politeness 0 to 1 (the lane width at its range in its own test).
RANGES = (
    "env.entry_speed_min=[0.0, 20.0]",
    "env.entry_speed_max=[20.0, 100.0]",
    "env.desired_speed_min=[10.0, 80.0]",
    "env.desired_speed_max=[30.0, 130.0]",
    "env.inflow_min=[400.0, 1600.0]",
    "env.inflow_max=[1600.0, 2400.0]",
    "env.mobil_politeness=[0.0, 1.0]",
    "env.mobil_threshold=[0.0, 0.3]",
    "env.mobil_rate=[0.1, 5.0]",
    "env.braking_rate=[0.0, 60.0]",
)


@pytest.mark.slow  # a long rollout (the quick tier keeps its hand-worked cases)
def test_ranged_keys_are_drawn_per_env_and_episode_within_their_ranges():
    cfg = config.load(overrides=(*HAZARDS, *RANGES, "env.lane_width=[3.0, 4.5]", "env.border=4.5"))
    env, p = jaxlc.make(cfg)
    assert set(p.drawn) == {"lane_width", *(o.split("=")[0][4:] for o in RANGES)}
    reset = jax.jit(jax.vmap(env.reset, (0, None)))
    _, s = reset(jax.random.split(jax.random.PRNGKey(0), 64), p)
    step = jax.jit(jax.vmap(env.step, (0, 0, None, None)))
    starts, before = [], s.episode
    for k in jax.random.split(jax.random.PRNGKey(1), 300):
        _, s, _, _, _, info = step(jax.random.split(k, 64), s, jnp.zeros(1), p)
        ended = np.asarray(info["reason"]) != 0
        for (lo, hi), old, new in zip(p.ranges, before, s.episode, strict=True):
            new = np.asarray(new)
            assert np.all((new >= lo - 1e-6) & (new <= hi + 1e-6))
            # a draw changes only as an episode ends, and the envs draw apart
            assert np.array_equal(np.asarray(old)[~ended], new[~ended])
            assert np.std(new) > 0.1 * (hi - lo)
        w = np.asarray(s.episode[p.drawn.index("lane_width")])
        rl_start = np.asarray(info["lane_change"])  # the RL phase starts one lane width out
        assert np.allclose(np.abs(np.asarray(info["offset"]))[rl_start], w[rl_start], atol=1e-3)
        starts.append(int(rl_start.sum()))
        before = s.episode
    assert sum(starts) > 20


@pytest.mark.slow  # a long rollout (the quick tier keeps its hand-worked cases)
def test_the_traffic_stays_physical_over_the_ranges():
    from benchmarks import traffic_properties as bench

    t = bench.check(32, 300, RANGES, chunk=300)
    assert t["overlaps"] == 0 and t["negative_speeds"] == 0 and t["off_road"] == 0
    assert t["unsafe_starts"] == 0
    assert t["lc_started"] > 10 and t["brake_started"] > 10


@pytest.mark.parametrize(
    "override, key",
    [
        ("env.inflow_min=[2000.0, 2500.0]", "env.inflow_min"),  # above inflow_max's 1600
        ("env.lane_width=[3.0, 4.0]", "env.lane_width"),  # past the border's 3.7
        ("env.mobil_politeness=[0.5, 0.2]", "env.mobil_politeness"),
        ("env.braking_rate=[0.0, 1e5]", "env.braking_rate"),
    ],
)
def test_a_bad_range_names_its_key(override, key):
    with pytest.raises(config.ConfigError, match=key.replace(".", r"\.")):
        config.load(overrides=(override,))


def test_the_suite_runs_each_setting_and_its_counts_add_up(smoke_run, tmp_path):
    """``--suite FILE``: a row per policy and setting in eval/suite/suite.csv, the commands
    split into declined, no gap, not started and lane changes, these into their ends; a
    harsher traffic changes what the policies meet, an operating range declines commands."""
    import csv

    from jaxlc.evaluate import main
    from jaxlc.evaluation import suite

    run_dir, _ = smoke_run
    path = tmp_path / "tiny.toml"
    path.write_text(
        'base = ["env.mobil=false"]\n[settings]\npaper = []\n'
        f"harsh = {json.dumps(HARSH)}\n"
        'ranged = ["env.operating_speed=[55.0, 250.0]"]\n'
    )
    lane_changes = ["--lane-changes", str(HARSH_LANE_CHANGES)]
    assert main([str(run_dir), "--suite", str(path), *lane_changes]) == 0
    with open(run_dir / "eval" / "suite" / "suite.csv") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == suite.FIELDS and (run_dir / "eval" / "suite" / "suite.png").is_file()
    by = {s: [r for r in rows if r["setting"] == s] for s in ("paper", "harsh", "ranged")}
    assert len({len(v) for v in by.values()}) == 1 and len(by["paper"]) == len(rows) // 3 > 1
    for r in rows:
        n = {k: int(r[k]) for k in (*suite.FIELDS[5:10], *heldout.ENDS)}
        assert n["lane_changes"] == sum(n[e] for e in heldout.ENDS) >= HARSH_LANE_CHANGES
        assert n["commands"] == n["lane_changes"] + n["declined"] + n["no_gap"] + n["not_started"]
        assert 0.0 <= float(r["success_lo"]) <= float(r["success_rate"]) <= float(r["success_hi"])
    assert all(int(r["declined"]) == 0 for r in by["paper"] + by["harsh"])
    assert all(int(r["declined"]) > 0 for r in by["ranged"])

    def seen(r):
        return (*(r[e] for e in heldout.ENDS), r["duration_s"], r["min_ttc_s"])

    assert any(seen(a) != seen(b) for a, b in zip(by["paper"], by["harsh"], strict=True))
    path.write_text('base = []\n[settings]\nbad = ["env.braking_rate=-1"]\n')
    with pytest.raises(config.ConfigError, match="suite setting 'bad'.*env.braking_rate"):
        suite.load(path)


def test_choose_takes_each_models_checkpoint_that_fails_least_and_later_evaluations_drive_it(
    smoke_run, tmp_path
):
    """``--choose``: per model, of its final checkpoint and those of ``eval.choose_episodes``,
    the one failing the fewest lane changes of the suite's settings on held-out seed
    ``eval.choose_seed`` (a tie: the later); ``eval/choice.json`` says so, and the suite run
    after it drives those checkpoints. A choice on the judged seed, or of nothing, is refused."""
    import csv
    import shutil

    from jaxlc.evaluate import main
    from jaxlc.evaluation import suite
    from jaxlc.evaluation.numbers import read
    from jaxlc.evaluation.protocol import final_checkpoints
    from jaxlc.evaluation.results import Choice, EvalError

    run = tmp_path / "run"  # a copy: the choice is the run's policy from now on
    shutil.copytree(smoke_run[0], run, ignore=shutil.ignore_patterns("eval"))
    path = tmp_path / "harsh.toml"
    path.write_text(f'base = ["env.mobil=false"]\n[settings]\nharsh = {json.dumps(HARSH)}\n')
    lane_changes = ["--lane-changes", str(HARSH_LANE_CHANGES)]
    assert main([str(run), "--choose", *lane_changes]) == 2  # eval.choose_episodes is []
    toml = run / "config.toml"
    text = toml.read_text().replace("choose_episodes = []", "choose_episodes = [20]")
    toml.write_text(text.replace("choose_lane_changes = 200", "choose_lane_changes = 12"))
    assert main([str(run), "--choose", "--suite", str(path), *lane_changes]) == 0
    choice = read(run / "eval" / "choice.json", Choice)
    assert (choice.seed, choice.lane_changes, choice.settings) == (1, 12, ["harsh"])
    failed: dict[str, dict[str, int]] = {}
    with open(run / "eval" / "heldout_choice_harsh" / "heldout.csv") as f:
        for r in csv.DictReader(f):
            if r["model"]:
                n = int(r["lane_changes"]) - int(r["success"])
                failed.setdefault(r["model"], {})[r["episode"]] = n
    assert choice.failures == failed and all(set(v) == {"20", "40"} for v in failed.values())
    assert choice.episode == suite.least_failed(failed)
    with open(run / "eval" / "heldout_suite_harsh" / "heldout.csv") as f:
        judged = {r["model"]: int(r["episode"]) for r in csv.DictReader(f) if r["model"]}
    assert judged == {m: choice.episode[m] for m in failed}
    # what every evaluation reads: a choice of episode 20 for model 0 alone, else the last
    (run / "eval" / "choice.json").write_text(json.dumps({"episode": {"0": 20}}))
    picked = {(m["model"], m["episode"]) for _, m in final_checkpoints(run)}
    assert (0, 20) in picked and (0, 40) not in picked and (1, 40) in picked
    assert {m["episode"] for _, m in final_checkpoints(run, chosen=False)} == {40}
    (run / "eval" / "choice.json").write_text(json.dumps({"episode": {"0": 60}}))
    with pytest.raises(EvalError, match="model 0 episode 60"):  # no such checkpoint
        final_checkpoints(run)
    with pytest.raises(config.ConfigError, match="eval.choose_seed"):
        config.load(overrides=("eval.choose_episodes=[20]", "eval.choose_seed=0"))
    # the rule by hand: the fewest failures, the later episode of a tie
    by_hand = {"0": {"20": 3, "40": 5}, "1": {"20": 2, "40": 2}, "2": {"4000": 0, "4200": 1}}
    assert suite.least_failed(by_hand) == {"0": 20, "1": 40, "2": 4000}


def test_any_road_draws_every_range_and_the_paper_and_default_draw_none():
    """configs/any_road.toml: every key of params.RANGED a range, its suite a valid file; the
    paper's and the default's configs keep constants and every command taken."""
    from jaxlc.evaluation import suite
    from jaxlc.sim.params import RANGED

    cfg = config.load(config.CONFIG_DIR / "any_road.toml")
    p = jaxlc.make(cfg)[1]
    assert set(p.drawn) == set(RANGED) and p.curvature_drawn and cfg.env.mobil and cfg.env.braking
    assert p.range_edge_share > 0 and p.manoeuvre_distance > 0 and p.yaw_rate_obs == "lane"
    settings = suite.load(cfg.eval.suite)
    assert {"paper", "reactive", "harsh", "stop_and_go"} <= set(settings)
    harsh = heldout.in_traffic(cfg, settings["harsh"]).env
    assert (
        harsh.braking_rate >= 10 * config.load(config.CONFIG_DIR / "reactive.toml").env.braking_rate
    )
    assert harsh.mobil_politeness == 0.0
    for name in ("paper.toml", "default.toml"):
        q = jaxlc.make(config.load(config.CONFIG_DIR / name))[1]
        assert q.drawn == () and q.operating_speed == () and not q.curvature_drawn, name
        assert q.range_edge_share == 0 and q.manoeuvre_distance == 0, name
        assert q.yaw_rate_obs == "absolute", name  # the paper's observation


def test_a_share_of_the_episodes_draws_each_range_at_its_ends():
    """``env.range_edge_share`` q: each drawn value is its range's min with probability q/2,
    its max with q/2, and otherwise uniform inside; q = 0 is the uniform draw itself."""
    from jaxlc.sim.state import draw_episode

    over = (*RANGES, "env.curvature=[-0.004, 0.004]")
    keys = jax.random.split(jax.random.PRNGKey(3), 4000)
    p0 = jaxlc.make(config.load(overrides=over))[1]
    pq = jaxlc.make(config.load(overrides=(*over, "env.range_edge_share=0.3")))[1]
    assert p0.range_edge_share == 0.0 and pq.drawn == p0.drawn
    uniform = np.asarray(jax.vmap(draw_episode, (0, None))(keys, p0))  # (keys, n drawn)
    edged = np.asarray(jax.vmap(draw_episode, (0, None))(keys, pq))
    u = np.asarray(
        jax.vmap(lambda k: jax.random.uniform(jax.random.fold_in(k, 2), (len(p0.drawn),)))(keys)
    )
    for i, (lo, hi) in enumerate(p0.ranges):
        assert np.array_equal(uniform[i], np.float32(lo) + u[:, i] * np.float32(hi - lo))
        ends = [np.isclose(edged[i], e, rtol=1e-6, atol=0.0) for e in (lo, hi)]  # float32's
        assert all(abs(np.mean(at) - 0.15) < 0.03 for at in ends)  # 5 sd of 4,000 draws
        inside = edged[i][~ends[0] & ~ends[1]]
        assert np.all((inside > lo) & (inside < hi))
        assert abs(np.mean(inside) - 0.5 * (lo + hi)) < 0.03 * (hi - lo)  # still centred
    # the road's curvature, drawn at the reset, has its ends too
    env = jaxlc.make(config.load(overrides=(*over, "env.range_edge_share=0.3")))[0]
    roads = np.asarray(jax.vmap(env.reset, (0, None))(keys[:64], pq)[1].curvature)
    assert 0.05 < np.mean(np.abs(roads) == np.float32(0.004)) < 0.6
