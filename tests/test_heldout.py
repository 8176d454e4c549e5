"""Held-out evaluation: the safety measures on hand-worked cases, the binomial and two-level
intervals (their coverage measured), the held-out key stream, claim (d) as a bound."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxlc import config
from jaxlc.evaluation import cases, heldout, keys, measures, safety
from jaxlc.evaluation.results import OUTCOMES, HeldoutRow
from jaxlc.sim import collision
from jaxlc.sim.env import EnvParams, LaneChangeEnv


def test_ttc_is_gap_over_closing_speed() -> None:
    # A follower at 25 m/s 20 m behind a leader at 20 m/s meets it in 20 / 5 = 4 s.
    assert float(safety.ttc(jnp.float32(20.0), 25.0, 20.0, True)) == pytest.approx(4.0)
    assert float(safety.ttc(jnp.float32(20.0), 20.0, 25.0, True)) == math.inf  # opening
    assert float(safety.ttc(jnp.float32(20.0), 25.0, 20.0, False)) == math.inf  # no vehicle
    assert float(safety.ttc(jnp.float32(-1.0), 20.0, 20.0, True)) == 0.0  # alongside


def test_headway_is_gap_over_the_followers_speed() -> None:
    assert float(safety.headway(jnp.float32(18.0), 20.0, True)) == pytest.approx(0.9)
    assert float(safety.headway(jnp.float32(18.0), 0.0, True)) == math.inf  # standing
    assert float(safety.headway(jnp.float32(-0.5), 20.0, True)) == 0.0


def test_constant_yaw_acceleration_has_jerk_v_times_alpha() -> None:
    """a_y = v*omega with omega = alpha*t: the 0.5 s average of da_y/dt is v*alpha once the
    window lies inside the manoeuvre, and ramps up while it still holds the straight run."""
    v, alpha, dt = 20.0, 0.5, 0.1
    n = safety.jerk_window(EnvParams(dt=dt))
    assert n == 5
    hist, jerks = jnp.zeros(n), []
    for t in range(1, 12):
        jerk, hist = safety.windowed_jerk(hist, jnp.float32(v * alpha * t * dt), dt)
        jerks.append(float(jerk))
    # Step t: the window spans a_y(t - 5) .. a_y(t); before the start a_y = 0.
    expect = [v * alpha * (t * dt - max(t - n, 0) * dt) / (n * dt) for t in range(1, 12)]
    np.testing.assert_allclose(jerks, expect, rtol=1e-5)
    assert jerks[-1] == pytest.approx(v * alpha)  # 10 m/s^3: over ISO 11270's 5


def test_collision_partner_by_lane_and_side() -> None:
    p = EnvParams()
    ego = type("E", (), {"x": jnp.float32(100.0), "target": jnp.int32(2)})
    x = jnp.zeros((3, 4)).at[2, 0].set(103.0).at[2, 1].set(98.0).at[1, 2].set(104.0)
    x = x.at[1, 3].set(97.0)
    tr = type("T", (), {"x": x, "lane": None})  # the paper's traffic: rows are lanes
    for (lane, slot), name in {
        (2, 0): "target_lead",
        (2, 1): "target_lag",
        (1, 2): "own_leader",
        (1, 3): "own_follower",
    }.items():
        mask = jnp.zeros((3, 4), bool).at[lane, slot].set(True)
        assert safety.PARTNERS[int(safety.partner(mask, tr, ego, p))] == name
    assert int(safety.partner(jnp.zeros((3, 4), bool), tr, ego, p)) == 0


def test_clopper_pearson_matches_the_closed_forms() -> None:
    # 0 failures in n: the one-sided upper bound is 1 - 0.05**(1/n).
    for n in (70, 210, 1000):
        assert heldout.upper_bound(0, n) == pytest.approx(1 - 0.05 ** (1 / n))
    assert heldout.upper_bound(0, 70) == pytest.approx(0.0419, abs=1e-4)
    lo, hi = heldout.clopper_pearson(210, 210)  # two-sided: lower end 0.025**(1/210)
    assert (lo, hi) == (pytest.approx(0.025 ** (1 / 210)), 1.0)
    lo, hi = heldout.clopper_pearson(5, 1000)
    assert lo < 0.005 < hi


def test_two_level_interval_covers_the_mean_over_seeds() -> None:
    """Seeds whose failure rates vary (Beta-drawn), 8 seeds x 1000 lane changes: the
    interval covers the population's mean success in about 95% of studies."""
    rng = np.random.default_rng(1)
    mean_fail, hits, trials = 0.004, 0, 200
    for t in range(trials):
        rates = rng.beta(0.8, 0.8 / mean_fail - 0.8, 8)
        k = 1000 - rng.binomial(1000, rates)
        lo, hi = heldout._two_level(k, np.full(8, 1000), seed=t)
        hits += lo <= 1 - mean_fail <= hi
    assert hits / trials >= 0.88, hits / trials


def test_cells_below_five_seeds_use_the_seeds_range() -> None:
    rows = [
        HeldoutRow(
            "④ k=1 D=4000",
            m,
            m,
            1,
            4000,
            success=s,
            lane_changes=1000,
            collision=1000 - s,
            norm_all=0.5,
            **dict(
                zip(("success_lo", "success_hi"), heldout.clopper_pearson(s, 1000), strict=True)
            ),
        )
        for m, s in enumerate((1000, 996, 999))
    ]
    (cell,) = heldout.cell_rows(rows)
    assert "range" in cell.interval
    assert cell.success_lo == rows[1].success_lo and cell.success_hi == 1.0
    assert cell.failures == 5 and cell.lane_changes == 3000
    d = heldout.claim_d([cell])
    assert d.verdict == "supported"  # 5 in 3000: bound 0.35% <= 1%
    assert "fewer than 0.35%" in d.figures
    worse = heldout.claim_d([dataclasses.replace(cell, failures=60, failure_bound=0.025)])
    assert worse.verdict == "not supported"  # 2% observed: the lower end is above 1%


def test_heldout_keys_are_a_stream_apart_from_the_protocols() -> None:
    def stream(seed: int, purpose: str) -> set:
        return {tuple(k) for k in np.asarray(keys.stream(seed, purpose, range(2000))).tolist()}

    held = stream(0, keys.HELDOUT)
    for seed in range(3):
        protocol = stream(seed, keys.PROTOCOL)
        assert not held & protocol
    assert held != stream(1, keys.HELDOUT)


def test_every_key_stream_is_the_one_committed_files_name() -> None:
    """``keys.stream`` gives the keys of the four functions it replaced, written out here as
    they were: ``case_keys`` (no tag), ``heldout_keys`` ("HELD"), ``validate_keys`` and
    ``keys_at`` ("VALD", "PILT"): committed results name those streams."""

    def old(seed: int, tag: int | None, indices: jax.Array) -> np.ndarray:
        root = jax.random.PRNGKey(seed)
        root = root if tag is None else jax.random.fold_in(root, tag)
        return np.asarray(jax.vmap(lambda i: jax.random.fold_in(root, i))(indices))

    tags = {keys.PROTOCOL: None, keys.HELDOUT: 0x48454C44}
    tags |= {keys.VALIDATE: 0x56414C44, keys.PILOT: 0x50494C54}
    for purpose, tag in tags.items():
        for seed in (0, 3):
            want = old(seed, tag, jnp.arange(7, 47))
            np.testing.assert_array_equal(
                np.asarray(keys.stream(seed, purpose, range(7, 47))), want
            )
        saved = [3, 99, 5]  # a saved case's indices (validate/cases.json), as keys_at took them
        want = old(1, tag, jnp.asarray(saved))
        np.testing.assert_array_equal(np.asarray(keys.stream(1, purpose, saved)), want)


def test_each_reducer_folds_the_live_steps_alone() -> None:
    """``measures.fold`` over three steps of two cases, the second live at the first step
    alone: sum, max, min, the last value and the first other than ``fill``; an ``at_end``
    measure waits for ``finish``; ``from_start`` starts from the start step's value."""
    from jaxlc.evaluation import measures

    fills = {"sum": 0.0, "max": -jnp.inf, "min": jnp.inf, "last": jnp.nan, "first": -1.0}
    ms = [measures.Measure(r, r, lambda s, p: s.reward, f) for r, f in fills.items()]
    ms += [measures.Measure("end", "last", lambda s, p: 10 * s.reward, 0.0, at_end=True)]
    ms += [measures.Measure("from0", "sum", lambda s, p: s.reward, from_start=True)]
    ms = tuple(ms)

    def step(v: list[float]) -> measures.Step:
        r = jnp.asarray([v], jnp.float32)  # (policies 1, cases 2)
        zero = jnp.zeros_like(r)
        return measures.Step(
            state=None,
            reason=zero,
            steps=zero,
            reward=r,
            info={},
            side=zero,
            performed=zero,
            lat_jerk=zero,
            long_jerk=zero,
            counted=zero,
        )

    out = measures.start(ms, step([5.0, 7.0]), None)
    for i, v in enumerate(([3.0, 4.0], [1.0, 9.0], [2.0, 8.0])):
        out = measures.fold(ms, out, step(v), jnp.asarray([[True, i == 0]]), None)
    out = measures.finish(ms, out, step([0.5, 0.25]), None)
    got = {k: np.asarray(v)[0].tolist() for k, v in out.columns().items()}
    assert got["sum"] == [6.0, 4.0] and got["max"] == [3.0, 4.0] and got["min"] == [1.0, 4.0]
    assert got["last"] == [2.0, 4.0] and got["first"] == [3.0, 4.0]
    assert got["end"] == [5.0, 2.5] and got["from0"] == [11.0, 11.0]
    with pytest.raises(ValueError, match="only a 'last'"):
        measures.register(measures.Measure("bad", "max", lambda s, p: s.reward, at_end=True))
    with pytest.raises(ValueError, match="registered already"):
        measures.register(measures.Measure("steps", "last", lambda s, p: s.steps))


@pytest.fixture(scope="module")
def smoke_cfg() -> config.Config:
    return config.load(config.CONFIG_DIR / "smoke.toml")


@pytest.mark.slow
def test_keys_for_lane_changes_hold_exactly_that_many(smoke_cfg: config.Config) -> None:
    found, started = cases.cases_for_lane_changes(smoke_cfg, 25, seed=3, batch=16)
    start, _ = cases.programs(smoke_cfg, 1500)
    alone = start(found)
    performed = np.asarray(alone.performed)
    assert performed.sum() == 25 and performed[-1]  # the last case is the 25th lane change
    # the cases handed on are those of the keys started afresh, bit for bit, whatever the batch
    for a, b in zip(jax.tree.leaves(started), jax.tree.leaves(alone), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    other, _ = cases.cases_for_lane_changes(smoke_cfg, 25, seed=3, batch=8)
    np.testing.assert_array_equal(np.asarray(other), np.asarray(found))
    # they are the held-out stream's first keys
    first = keys.stream(3, keys.HELDOUT, range(len(found)))
    np.testing.assert_array_equal(np.asarray(first), np.asarray(found))


@pytest.mark.slow
def test_rollout_jerk_and_ttc_match_a_replay_by_hand(smoke_cfg: config.Config) -> None:
    """A constant full-left policy on held-out cases; one case replayed with env.step: the
    rollout's peak windowed jerks (lateral and longitudinal), peak longitudinal acceleration,
    minimum lag TTC and UN R79's manoeuvre (the step the body first reaches into the target
    lane, the first after it with no corner left in the origin lane) equal the replay's."""
    found, _ = cases.cases_for_lane_changes(smoke_cfg, 3, seed=0, batch=8)
    out = cases.evaluate_act(smoke_cfg, lambda obs: jnp.ones((obs.shape[0], 1)), keys=found)
    start, _ = cases.programs(smoke_cfg, 1500)
    cs = start(found)
    c = int(np.nonzero(np.asarray(cs.performed))[0][0])
    p = EnvParams.from_config(smoke_cfg.env, gamma=smoke_cfg.ddpg.gamma)
    env, state = LaneChangeEnv(), jax.tree.map(lambda a: a[c], cs.state)
    step = jax.jit(lambda k, s: env.step(k, s, jnp.ones(1), p))
    a_y, lag_ttc, entered = [float(state.ego.v * state.ego.omega)], [], False
    a_x = [float(state.ego.accel)]
    origin, lcm = p.lanes // 2, [-1, -1]  # R79's manoeuvre: first step in, first step across
    for n in range(1, 201):
        # the lag counts from the step the body's corners first reach into the target lane
        entered = entered or _reaches(state, int(state.ego.target), p)
        lag_ttc.append(lag_ttc_of(state, p) if entered else math.inf)
        _, state, _, term, trunc, info = step(jax.random.fold_in(cs.key[c], state.time), state)
        a_y.append(float(state.ego.v * state.ego.omega))
        a_x.append(float(state.ego.accel))
        if lcm[0] < 0 and _reaches(state, int(state.ego.target), p):
            lcm[0] = n
        if lcm[0] >= 0 and lcm[1] < 0 and not _reaches(state, origin, p):
            lcm[1] = n
        if int(info["reason"]) != 0:
            break
    entered = entered or _reaches(state, int(state.ego.target), p)
    lag_ttc.append(lag_ttc_of(state, p) if entered else math.inf)
    assert not _reaches(jax.tree.map(lambda a: a[c], cs.state), int(state.ego.target), p)
    n = safety.jerk_window(p)

    def peak_jerk(a: list[float]) -> float:  # each step: the mean slope over the last 0.5 s
        padded = np.concatenate([np.full(n, a[0]), a[1:]])  # held at its start value before
        return float(np.max(np.abs(padded[n:] - padded[:-n]) / (n * p.dt)))

    assert int(out["reason"][0][c]) == int(info["reason"])
    assert out["peak_lat_jerk"][0][c] == pytest.approx(peak_jerk(a_y), rel=1e-4)
    assert out["peak_long_jerk"][0][c] == pytest.approx(peak_jerk(a_x), rel=1e-4, abs=1e-6)
    assert out["peak_long_acc"][0][c] == pytest.approx(np.max(np.abs(a_x[1:])), rel=1e-6)
    assert out["peak_long_jerk"][0][c] > 0  # the IDM ego's speed changes in the manoeuvre
    assert out["min_ttc"][0][c][1] == pytest.approx(min(lag_ttc), rel=1e-4)
    assert 0 < lcm[0] < lcm[1]  # the body crossed over in the replay, so the test can fail
    assert [int(out["lcm_start"][0][c]), int(out["lcm_end"][0][c])] == lcm


def lag_ttc_of(state, p) -> float:
    gap = state.ego.x - p.vehicle_length - state.nb.b1_x
    return float(safety.ttc(gap, state.nb.b1_v, state.ego.v, state.nb.has_b1))


def _reaches(state, lane: int, p) -> bool:
    """Whether any corner of the ego's body (front bumper at x, centre line at y, heading
    psi) lies past the border of ``lane`` toward it, or inside it."""
    e = state.ego
    length, width, psi = float(p.vehicle_length), float(p.vehicle_width), float(e.psi)
    ys = [
        float(e.y) + a * math.sin(psi) + b * math.cos(psi)
        for a in (-length / 2, length / 2)
        for b in (-width / 2, width / 2)
    ]
    lo, hi = lane * float(p.lane_width), (lane + 1) * float(p.lane_width)
    return max(ys) > lo and min(ys) < hi


@pytest.mark.slow
def test_headway_counts_once_the_body_overlaps_the_lane() -> None:
    """Target-lane vehicles count from the ego's first overlap with the target lane on (also if
    it swings back), the own leader while the body overlaps the own lane, centre still in it."""
    env = LaneChangeEnv()
    p = EnvParams()
    _, state = env.reset(jax.random.key(0), p)
    w, origin = float(p.lane_width), p.lanes // 2
    centre = (origin + 0.5) * w

    def at(y: float, psi: float = 0.0):
        ego = state.ego.replace(y=jnp.float32(y), psi=jnp.float32(psi), target=origin + 1)
        return state.replace(ego=ego)

    half_w = 0.5 * float(p.vehicle_width)
    entered = jnp.bool_(False)
    seen = []
    for y in (
        centre,
        centre + w / 2 - half_w - 0.01,
        centre + w / 2 - half_w + 0.01,
        centre + w / 2 + 0.01,
        centre,
    ):
        mask, entered = safety.counted(at(y), p, entered)
        seen.append(tuple(bool(v) for v in mask))
    assert seen == [
        (False, False, True),  # wholly in its own lane: its leader only
        (False, False, True),  # 1 cm short of the border
        (True, True, True),  # 1 cm over: the target lane's lead and lag count from now on
        (True, True, False),  # centre over the border: the own lane's leader no longer
        (True, True, True),  # back in its own lane: the target lane's vehicles still count
    ]
    # a heading turns the box: its corner reaches over before its side would
    y = centre + w / 2 - half_w - 0.05
    assert not bool(safety.counted(at(y), p, jnp.bool_(False))[1])
    assert bool(safety.counted(at(y, 0.1), p, jnp.bool_(False))[1])
    assert _reaches(at(y, 0.1), origin + 1, p) and not _reaches(at(y), origin + 1, p)


def test_the_r79_norm_times_the_manoeuvre_line_to_line() -> None:
    """Hand-worked, dt = 0.1 s: a success whose body enters the target lane at RL step 12 and
    leaves the origin lane at step 52 took 4.0 s over the lines (inside R79's 5 s) although the
    whole RL phase took 8.0 s; from 12 to 63 it is 5.1 s (outside); a timeout that entered but
    never crossed has no manoeuvre duration (inf), and its start counts."""
    success, timeout = OUTCOMES.index("success"), OUTCOMES.index("timeout")
    one = np.ones((1, 3), np.float32)
    out = {
        "reason": np.array([[success, success, timeout]]),
        "steps": np.array([[80, 80, 150]]),
        "lcm_start": np.array([[12, 12, 30]]),
        "lcm_end": np.array([[52, 63, -1]]),
        "peak_lat_acc": one,
        "peak_lat_jerk": one,
        "min_ttc": np.full((1, 3, 3), 9.0, np.float32),
        "min_thw": np.full((1, 3, 3), 9.0, np.float32),
        **{k: one for k in heldout.LONGITUDINAL},
    }
    m = heldout.lane_change_measures(out, 0, 0.1)
    np.testing.assert_allclose(m["duration_s"], [8.0, 8.0, np.inf])
    np.testing.assert_allclose(m["lcm_s"], [4.0, 5.1, np.inf])
    np.testing.assert_allclose(m["lcm_start_s"], [1.2, 1.2, 3.0])
    assert m["norm_lcm_s"].tolist() == [True, False, False]
    assert m["norm_all"].tolist() == [True, False, False]


def test_clearance_is_the_distance_between_the_boxes_by_hand() -> None:
    """The paper's traffic (rows are lanes), a straight road, the ego heading along it at
    x = 100 (front bumper), y = 5.55 (lane 1's centre): a body 3 m ahead in its lane is 3 m
    away; one in lane 2 whose rear is 4 m ahead is hypot(4, 3.7 - 1.8) away (boxes 1.8 m
    wide, centres 3.7 m apart); one overlapping is 0, as ``overlaps`` says; an empty slot inf.
    The margin measure takes the least and is exactly 0 on a collision's step."""
    p = EnvParams()
    L, W = p.vehicle_length, p.vehicle_width
    assert (L, W, p.lane_width) == (5.0, 1.8, 3.7)
    ego = type("E", (), {"x": jnp.float32(100.0), "y": jnp.float32(5.55), "psi": 0.0})
    x = jnp.zeros((3, 3)).at[1, 0].set(100 + L + 3).at[2, 0].set(100 + L + 4)
    x = x.at[1, 1].set(100 - L + 1)  # its front 1 m into the ego's rear
    active = jnp.zeros((3, 3), bool).at[1, :2].set(True).at[2, 0].set(True)
    tr = type("T", (), {"x": x, "lane": None, "active": active})
    gap = np.asarray(collision.clearance(tr, ego, p))
    assert gap[1, 0] == pytest.approx(3.0, abs=1e-4)
    assert gap[2, 0] == pytest.approx(math.hypot(4.0, 3.7 - W), abs=1e-4)
    assert gap[1, 1] == 0.0 and np.isinf(gap[0]).all() and np.isinf(gap[2, 1:]).all()
    assert (gap == 0).tolist() == np.asarray(collision.overlaps(tr, ego, p)).tolist()
    # turned by 90 degrees the ego's box is 1.8 long and 5 wide: lane 2's body, 4 m ahead of
    # the front bumper and 3.7 - 3.4 = 0.3 m beside, is hypot(4, 0.3) away
    ego.psi = jnp.float32(math.pi / 2)
    far = float(collision.clearance(tr, ego, p)[2, 0])
    assert far == pytest.approx(math.hypot(4.0, 3.7 - 0.5 * (L + W)), abs=1e-4)


@pytest.fixture(scope="module")
def margins(smoke_cfg: config.Config) -> dict[str, np.ndarray]:
    """24 held-out lane changes: the scripted controller (succeeds), a zero actor (times
    out) and a constant full-left action (out of bounds, either side)."""
    found, started = cases.cases_for_lane_changes(smoke_cfg, 24, seed=0, batch=32)
    zero = jax.tree.map(jnp.zeros_like, cases.init_actor(smoke_cfg))
    out, _, info = cases.evaluate_policies(smoke_cfg, [None, zero], [1, 1], started=started)
    left = cases.evaluate_act(smoke_cfg, lambda o: jnp.ones((o.shape[0], 1)), started=started)
    both = {k: np.concatenate([v, left[k]]) for k, v in out.items()}
    return {k: v[:, info["performed"]] for k, v in both.items()}


@pytest.mark.slow  # a long rollout (the quick tier keeps its hand-worked cases)
def test_each_margin_is_zero_exactly_on_its_failure(margins: dict[str, np.ndarray]) -> None:
    reason = margins["reason"]
    assert {int(r) for r in reason.ravel()} >= {1, 2, 4}  # success, out of bounds, timeout
    for kind, name in measures.MARGINS.items():
        failed = reason == OUTCOMES.index(kind)
        m = margins[name]
        assert (m[failed] == 0).all(), kind
        assert (m[reason == OUTCOMES.index("success")] > 0).all(), kind
    # a lane change that ends in any other way keeps its gap: > 0 unless it collided
    hit = reason == OUTCOMES.index("collision")
    assert ((margins["margin_gap"] == 0) == hit).all()
    # every lane change had a vehicle about it, and at most the limit's 10 s left
    assert np.isfinite(margins["margin_gap"]).all() and (margins["margin_time"] <= 10.0).all()
