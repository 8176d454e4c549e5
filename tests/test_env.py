"""The simulator: reward, kinematics, IDM, gap selection, episode rules, vmap, controller."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxlc
from jaxlc import config
from jaxlc.sim import env as E
from jaxlc.sim import gap, idm, kinematics, reward
from jaxlc.sim import observation as O
from jaxlc.sim import road as R
from jaxlc.sim.controller import scripted_action


@pytest.fixture(scope="module")
def env_params():
    return jaxlc.make()


@pytest.fixture(scope="module")
def rollout(env_params):
    """Jitted ``(states, key, actions_fn_id) -> outputs`` over T steps, shared by tests."""
    env, p = env_params

    @partial(jax.jit, static_argnames=("steps", "policy"))
    def run(obs, state, key, params, steps, policy):
        def body(carry, k):
            obs, state = carry
            k_act, k_step = jax.random.split(k)
            n = obs.shape[0]
            if policy == "scripted":
                a = scripted_action(obs, params)
            elif policy == "random":
                a = jax.random.uniform(k_act, (n, 1), minval=-1.0, maxval=1.0)
            else:  # "wild": extreme and non-finite actions
                pick = jax.random.randint(k_act, (n, 1), 0, 6)
                wild = jnp.array([jnp.nan, jnp.inf, -jnp.inf, 1e30, -1e30, 0.3])
                a = wild[pick]
            keys = jax.random.split(k_step, n)
            obs, state, r, term, trunc, info = jax.vmap(env.step, (0, 0, 0, None))(
                keys, state, a, params
            )
            tr = state.traffic
            out = {
                "reason": info["reason"],
                "rl": info["rl_step"],
                "steps": info["episode_steps"],
                "reward": r,
                "obs_finite": jnp.all(jnp.isfinite(obs), axis=-1),
                "x": tr.x,
                "v": tr.v,
                "active": tr.active,
                "tail": tr.tail,
                "ego_finite": jnp.isfinite(state.ego.x)
                & jnp.isfinite(state.ego.y)
                & jnp.isfinite(state.ego.v)
                & jnp.isfinite(state.ego.psi),
            }
            return (obs, state), out

        return jax.lax.scan(body, (obs, state), jax.random.split(key, steps))

    return run


@pytest.fixture(scope="module")
def reset_batch(env_params):
    env, p = env_params
    return jax.jit(jax.vmap(env.reset, (0, None)))


# --- reward, eqs. (8)-(11) -----------------------------------------------------------------


def paper_terms(omega, a_lat, offset, collided, p):
    """``(r_s, r_e, r_d)``: the paper's terms for one RL step, each times reward_scale."""
    x = reward.Inputs(omega, a_lat, offset, collided)
    return tuple(p.reward_scale * t.fn(x, p) for t in reward.PAPER)


def equilibrium_gap(v: float, v0: float, time_headway: float, s0: float, delta: float) -> float:
    """Net gap at which a follower at steady speed ``v`` (behind a leader at ``v``) has a = 0."""
    return (s0 + v * time_headway) / (1.0 - (v / v0) ** delta) ** 0.5


def test_reward_matches_paper_inside_and_beyond_border(env_params):
    _, p = env_params
    # Inside D: omega 0.05 rad/s, a_lat 0.2 rad/s^2, offset -1.5 m.
    r_s, r_e, r_d = paper_terms(
        jnp.float32(0.05), jnp.float32(0.2), jnp.float32(-1.5), jnp.bool_(False), p
    )
    assert r_s == pytest.approx(-10.0 * 0.05 - 5.0 * 0.2, rel=1e-6)
    assert r_e == pytest.approx(-0.075 * 0.1, rel=1e-6)
    assert r_d == pytest.approx(-1.5, rel=1e-6)
    # Beyond D = 3.7 m: the penalty is |dd| * 10 / (1 - 0.98) = 500 |dd|.
    _, _, r_d = paper_terms(
        jnp.float32(0.0), jnp.float32(0.0), jnp.float32(3.8), jnp.bool_(False), p
    )
    assert r_d == pytest.approx(-3.8 * 10.0 / 0.02, rel=1e-5)
    # At exactly D the ordinary term applies (eq. 11's first case).
    _, _, r_d = paper_terms(
        jnp.float32(0.0), jnp.float32(0.0), jnp.float32(3.7), jnp.bool_(False), p
    )
    assert r_d == pytest.approx(-3.7, rel=1e-6)
    # A collision costs the out-of-bounds penalty at max(|dd|, D).
    _, _, r_d = paper_terms(
        jnp.float32(0.0), jnp.float32(0.0), jnp.float32(0.4), jnp.bool_(True), p
    )
    assert r_d == pytest.approx(-3.7 * 500.0, rel=1e-5)


def test_end_reason_fires_exactly_at_thresholds(env_params):
    _, p = env_params
    f32 = jnp.float32

    def reason(offset, psi=0.0, omega=0.0, steps=5, collided=False):
        return int(
            reward.end_reason(
                f32(offset), f32(psi), f32(omega), jnp.int32(steps), jnp.bool_(collided), p
            )
        )

    up = lambda x: float(np.nextafter(np.float32(x), np.float32(np.inf)))  # noqa: E731
    assert reason(3.7) == reward.NONE
    assert reason(up(3.7)) == reward.OUT_OF_BOUNDS
    assert reason(-up(3.7)) == reward.OUT_OF_BOUNDS
    assert reason(0.2, 0.02, -0.02) == reward.SUCCESS
    assert reason(up(0.2), 0.0, 0.0) == reward.NONE
    assert reason(0.1, up(0.02), 0.0) == reward.NONE
    assert reason(0.1, 0.0, up(0.02)) == reward.NONE
    assert reason(1.0, steps=99) == reward.NONE
    assert reason(1.0, steps=100) == reward.TIMEOUT
    assert reason(0.0, collided=True) == reward.COLLISION


def test_a_time_limit_that_follows_the_speed_worked_by_hand(env_params):
    """``env.manoeuvre_distance`` D = 150 m, limit 10 s, longest 30 s, dt 0.1 s: a manoeuvre
    at v m/s times out after clip(150 / v, 10, 30) s: 25 m/s 10 s (100 steps), 10 m/s 15 s,
    7.5 m/s 20 s, 2 m/s and standing 30 s (the longest); off, 10 s at any speed."""
    _, off = env_params
    on = off.replace(manoeuvre_distance=150.0, manoeuvre_time_max=30.0)
    assert reward.step_limit(off) == 100 and reward.step_limit(on) == 300  # the programs' cap

    def reason(p, v, steps):
        f32 = jnp.float32
        args = f32(1.0), f32(0.0), f32(0.0), jnp.int32(steps), jnp.bool_(False), p, f32(v)
        return int(reward.end_reason(*args))

    for v, steps in ((25.0, 100), (10.0, 150), (7.5, 200), (2.0, 300), (0.0, 300)):
        assert reason(on, v, steps - 1) == reward.NONE, v
        assert reason(on, v, steps) == reward.TIMEOUT, v
        assert reason(off, v, 99) == reward.NONE and reason(off, v, 100) == reward.TIMEOUT
    with pytest.raises(ValueError, match="speed"):  # on, the limit needs the speed
        reward.end_reason(jnp.float32(1.0), 0.0, 0.0, jnp.int32(5), jnp.bool_(False), on)
    bad = ["env.manoeuvre_distance=150.0", "env.manoeuvre_time_max=5.0"]
    with pytest.raises(config.ConfigError, match="env.manoeuvre_time_max"):
        config.load(None, bad)


def test_each_timeout_under_a_speed_limit_comes_when_its_speed_says():
    """With ``env.manoeuvre_distance`` on, a policy that never steers times out, each on the
    first step whose count reaches what the speed then allows (``reward.steps_allowed``; one
    more where the ego sped up), and not all at 10 s."""
    cfg = config.load(None, ["env.manoeuvre_distance=300.0", "env.manoeuvre_time_max=40.0"])
    env, p = jaxlc.make(cfg)
    keys = jax.random.split(jax.random.PRNGKey(0), 16)
    obs, s = jax.jit(jax.vmap(env.reset, (0, None)))(keys, p)
    step = jax.jit(jax.vmap(env.step, (0, 0, 0, None)))
    still = jnp.zeros((16, 1))
    ends = []  # (steps, allowed now, allowed a step before) of each timeout
    before = np.asarray(reward.steps_allowed(s.ego.v, p))
    for k in jax.random.split(jax.random.PRNGKey(1), 900):
        obs, s, _, _, _, info = step(jax.random.split(k, 16), s, still, p)
        out = np.asarray(info["reason"]) == reward.TIMEOUT
        allowed = np.asarray(reward.steps_allowed(s.ego.v, p))
        ends += list(zip(np.asarray(s.ego.steps)[out], allowed[out], before[out], strict=True))
        before = allowed
    assert len(ends) >= 5
    assert all(a <= n < b + 1 for n, a, b in ends), ends
    assert len({n for n, *_ in ends}) > 1 and max(n for n, *_ in ends) > 100


# --- kinematics ------------------------------------------------------------------------------


def test_constant_yaw_acceleration_matches_closed_form():
    a, v, dt, n = 0.05, 15.0, 0.1, 60
    step = jax.jit(kinematics.lateral_step)
    x = y = psi = omega = jnp.float32(0.0)
    for _ in range(n):
        x, y, psi, omega = step(x, y, psi, omega, v, a, 0.0, dt)
    # Semi-implicit Euler, exactly: omega_n = a n dt, psi_n = a dt^2 n (n+1) / 2.
    assert float(omega) == pytest.approx(a * n * dt, rel=1e-5)
    assert float(psi) == pytest.approx(a * dt**2 * n * (n + 1) / 2, rel=1e-5)
    # Position against the continuous closed form x = int v cos(a t^2/2), y = int v sin(...),
    # evaluated by fine quadrature; semi-implicit Euler is first order, so within O(dt).
    t = np.linspace(0.0, n * dt, 200001)
    ang = a * t**2 / 2
    x_ref = np.trapezoid(v * np.cos(ang), t)
    y_ref = np.trapezoid(v * np.sin(ang), t)
    assert float(x) == pytest.approx(x_ref, abs=0.01 * x_ref)
    assert float(y) == pytest.approx(y_ref, rel=0.08)


@pytest.mark.parametrize("kappa", [0.002, -0.004])
def test_frenet_step_follows_a_straight_world_line_on_a_curved_road(kappa):
    """With no yaw rate the ego drives a straight line of the world; on a road bending by
    kappa (reference circle of radius R = 1/kappa) the line's Frenet coordinates are known
    in closed form: after a distance l, d = R - sign(R) sqrt(R^2 + l^2), s = R atan(l / R)
    and the heading relative to the road psi = -atan(l / R). Semi-implicit Euler at a small
    dt converges to them (a psi' without the exact kappa*s' term would not)."""
    v, dt, n = 25.0, 5e-3, 1600  # 200 m
    y_ref = 5.55

    def body(c, _):
        x, y, psi, omega = c
        return kinematics.lateral_step(x, y, psi, omega, v, 0.0, kappa, dt, y_ref), None

    zero = jnp.float32(0.0)
    (x, y, psi, _), _ = jax.lax.scan(body, (zero, jnp.float32(y_ref), zero, zero), None, n)
    R, length = 1.0 / kappa, v * dt * n
    d_want = R - np.sign(R) * np.hypot(R, length)
    assert abs(d_want) > 5.0  # the line leaves the reference by more than a lane
    assert float(y - y_ref) == pytest.approx(d_want, abs=0.05)
    assert float(x) == pytest.approx(R * np.arctan(length / R), abs=0.05)
    assert float(psi) == pytest.approx(-np.arctan(length / R), abs=1e-3)


def test_holding_a_line_of_a_curve_takes_its_yaw_rate():
    """psi = 0 and omega = kappa_d * v keep the ego on its line: d stays, psi stays 0, and the
    yaw rate relative to the lane's is 0; s advances by v dt / (1 - kappa d)."""
    kappa, d, v, dt = 0.003, -3.7, 20.0, 0.1
    omega = float(kinematics.path_curvature(kappa, d)) * v
    x, y, psi, om = kinematics.lateral_step(0.0, d, 0.0, omega, v, 0.0, kappa, dt)
    assert float(y) == pytest.approx(d, abs=1e-6) and abs(float(psi)) < 1e-7
    assert float(x) == pytest.approx(v * dt / (1 - kappa * d), rel=1e-6)
    assert abs(float(kinematics.relative_yaw_rate(om, psi, v, kappa, y))) < 1e-6
    assert float(kinematics.relative_yaw_rate(om, psi, v, 0.0, y)) == pytest.approx(omega)


# --- IDM -----------------------------------------------------------------------------------


def test_idm_matches_formula_on_hand_cases(env_params):
    _, p = env_params
    f = partial(
        idm.idm_acceleration, a_max=1.5, b=2.0, time_headway=1.5, s0=2.0, delta=4.0, b_max=9.0
    )
    # Free road at half the desired speed: 1.5 * (1 - 0.5^4).
    assert float(f(10.0, 20.0, idm.NO_LEADER_GAP, 10.0)) == pytest.approx(1.40625, rel=1e-4)
    # v = 10, leader 8 m/s at 30 m: s* = 2 + 15 + 10*2/(2*sqrt(3)) = 22.7735.
    s_star = 2 + 15 + 20 / (2 * np.sqrt(3.0))
    want = 1.5 * (1 - 0.5**4 - (s_star / 30.0) ** 2)
    assert float(f(10.0, 20.0, 30.0, 8.0)) == pytest.approx(want, rel=1e-5)
    # Braking is clipped at b_max.
    assert float(f(30.0, 30.0, 1.0, 0.0)) == pytest.approx(-9.0)


def _quiet_state(env, p, key):
    """A reset state with no traffic and no inflow (timers far in the future)."""
    _, s = env.reset(key, p.replace(warmup_steps=1))
    tr = s.traffic
    return s.replace(
        traffic=tr.replace(active=jnp.zeros_like(tr.active), timer=jnp.full_like(tr.timer, 1e9))
    )


@pytest.mark.slow
@pytest.mark.parametrize("kappa", [0.0, 0.005])
def test_platoon_settles_to_equilibrium_gap(env_params, kappa):
    """IDM's equilibrium gap holds in metres along the lane, on a curve too: lane 0 lies
    outside the road's centre line of a left bend (d < 0), so its s runs slower than its
    metres, by the lane scale 1 - kappa*d."""
    env, p = env_params
    p = p.replace(road_length=1e5, curvature=jnp.float32(kappa))
    s = _quiet_state(env, p, jax.random.PRNGKey(0))
    n = 5
    x = jnp.zeros_like(s.traffic.x).at[0, :n].set(400.0 - 60.0 * jnp.arange(n))
    v0 = jnp.full_like(x, 30.0).at[0, 0].set(20.0)  # the platoon's head wants 20 m/s
    tr = s.traffic.replace(
        x=x,
        v=jnp.full_like(x, 15.0),
        v0=v0,
        active=jnp.zeros_like(s.traffic.active).at[0, :n].set(True),
        tail=s.traffic.tail.at[0].set(n),
    )
    s = s.replace(traffic=tr)

    @jax.jit
    def run(s):
        def body(s, k):
            return E._advance(k, s, jnp.zeros(1), p, spawn=False)[0], None

        return jax.lax.scan(body, s, jax.random.split(jax.random.PRNGKey(1), 3000))[0]

    s = run(s)
    scale = 1.0 - kappa * float(R.lane_offset(0, p))
    assert (scale > 1.0) == (kappa > 0)
    gaps = np.asarray((s.traffic.x[0, : n - 1] - s.traffic.x[0, 1:n]) * scale - 5.0)
    want = equilibrium_gap(20.0, 30.0, 1.5, 2.0, 4.0)
    np.testing.assert_allclose(np.asarray(s.traffic.v[0, :n]), 20.0, rtol=1e-3)
    np.testing.assert_allclose(gaps, want, rtol=5e-3)


def test_long_random_run_keeps_traffic_physical(env_params, rollout, reset_batch):
    env, p = env_params
    n_env, steps = 128, 400  # 51,200 env-steps
    obs, state = reset_batch(jax.random.split(jax.random.PRNGKey(3), n_env), p)
    _, out = rollout(obs, state, jax.random.PRNGKey(4), p, steps=steps, policy="random")
    x, v, active, tail = (np.asarray(out[k]) for k in ("x", "v", "active", "tail"))
    assert np.isfinite(x).all() and np.isfinite(v).all()
    assert (v[active] >= 0.0).all()
    assert np.asarray(out["obs_finite"]).all() and np.asarray(out["ego_finite"]).all()
    S = p.slots_per_lane
    # Slots of a lane: the occupied ones are the newest n written before `tail`, and going
    # back from the newest the positions increase by at least one vehicle length.
    n_act = active.sum(-1)  # (T, envs, lanes)
    age = (tail[..., None] - 1 - np.arange(S)) % S  # slot index of the j-th newest
    occ_by_age = np.take_along_axis(active, age, axis=-1)
    assert (occ_by_age == (np.arange(S) < n_act[..., None])).all(), "occupied slots not contiguous"
    x_by_age = np.take_along_axis(x, age, axis=-1)
    both = occ_by_age[..., 1:] & occ_by_age[..., :-1]
    gaps = x_by_age[..., 1:] - x_by_age[..., :-1] - p.vehicle_length
    assert (gaps[both] >= 0.0).all(), f"IDM vehicles overlap: min net gap {gaps[both].min()}"
    assert active.sum() > 0.3 * active.size / 2, "the road should carry traffic"


def test_wild_actions_keep_the_simulator_finite(env_params, rollout, reset_batch):
    env, p = env_params
    obs, state = reset_batch(jax.random.split(jax.random.PRNGKey(5), 64), p)
    _, out = rollout(obs, state, jax.random.PRNGKey(6), p, steps=400, policy="wild")
    assert np.asarray(out["obs_finite"]).all()
    assert np.asarray(out["ego_finite"]).all()
    assert np.isfinite(np.asarray(out["reward"])).all()
    assert (np.asarray(out["rl"]).sum()) > 1000, "wild actions must reach the RL phase"


# --- gap selection -------------------------------------------------------------------------


def _lane(xs, vs, v0s=None, slots=8):
    x = np.zeros(slots, np.float32)
    v = np.zeros(slots, np.float32)
    v0 = np.full(slots, 30.0, np.float32)
    act = np.zeros(slots, bool)
    x[: len(xs)], v[: len(vs)], act[: len(xs)] = xs, vs, True
    if v0s is not None:
        v0[: len(v0s)] = v0s
    return jnp.asarray(x), jnp.asarray(v), jnp.asarray(v0), jnp.asarray(act)


@pytest.mark.parametrize(
    "xs, vs, accept",
    [
        ([], [], True),  # empty lane
        ([160.0, 55.0], [20.0, 20.0], True),  # lead 55 m ahead, lag 40 m behind, same speed
        # Lead net gap = s0 + 0.5 s * v_ego = 12 m exactly: acceptable; 11.9 m: not.
        ([117.0, 55.0], [20.0, 20.0], True),
        ([116.9, 55.0], [20.0, 20.0], False),
        # Lag 20 m behind: enough by the gap rule (>= 2 + 0.5*30 m) but closing at 10 m/s,
        # so its IDM deceleration with the ego as leader is below -b_safe = -4 m/s^2.
        ([300.0, 75.0], [20.0, 30.0], False),
        ([300.0, 75.0], [20.0, 10.0], True),  # same place, slower: it stays behind
        ([300.0, 93.5], [20.0, 0.0], False),  # stopped lag 1.5 m behind: under s0
        # 15 m behind at the same speed: gap rule met (>= 12 m) but IDM brakes at -5.6.
        ([300.0, 80.0], [20.0, 20.0], False),
    ],
)
def test_gap_beside_acceptance(env_params, xs, vs, accept):
    _, p = env_params
    x_ego, v_ego = 100.0, 20.0
    nb = gap.neighbours(*_lane(xs, vs), jnp.float32(x_ego))
    assert bool(gap.beside_acceptable(nb, jnp.float32(x_ego), jnp.float32(v_ego), p)) is accept


@pytest.mark.parametrize("min_ttc, accept", [(0.0, True), (2.5, True), (4.0, False)])
def test_gap_acceptance_by_time_to_collision(env_params, min_ttc, accept):
    """The scene of the held-out collisions: the ego at 0.6 m/s, the lead 2.95 m ahead (net),
    a lag at 13.2 m/s 37.9 m behind. MOBIL's test passes (the lag would brake at -3.6 m/s^2
    if it took the ego as its leader), but a lag that does not yield keeps its speed and
    comes within s0 of the ego after (37.9 - 2) / 12.6 = 2.85 s."""
    _, p = env_params
    p = p.replace(gap_min_ttc=min_ttc)
    x_ego, v_ego = 100.0, 0.6
    xs, vs = [x_ego + 5.0 + 2.95, x_ego - 5.0 - 37.9], [5.0, 13.2]
    nb = gap.neighbours(*_lane(xs, vs, v0s=[30.0, 30.0]), jnp.float32(x_ego))
    assert bool(gap.beside_acceptable(nb, jnp.float32(x_ego), jnp.float32(v_ego), p)) is accept
    assert config.Config().env.gap_min_ttc == 4.0  # the default rejects it


def _lag_scene(env, p, yielding):
    """Ego under RL control at x=200 m, 15 m/s, holding its lane; in the target lane a lag
    25 m behind at 25 m/s that wants 30 m/s."""
    s = _quiet_state(env, p, jax.random.PRNGKey(7))
    tr = s.traffic
    x = jnp.zeros_like(tr.x).at[0, 0].set(175.0)
    tr = tr.replace(
        x=x,
        v=jnp.zeros_like(x).at[0, 0].set(25.0),
        v0=jnp.full_like(x, 30.0),
        active=jnp.zeros_like(tr.active).at[0, 0].set(True),
        tail=tr.tail.at[0].set(1),
    )
    ego = s.ego.replace(
        phase=jnp.int32(E.RL),
        x=jnp.float32(200.0),
        v=jnp.float32(15.0),
        v0=jnp.float32(15.0),
        target=jnp.int32(0),
        yielding=jnp.bool_(yielding),
    )
    s = s.replace(traffic=tr, ego=ego)
    nb, lg, lv = O.observe_lanes(tr, ego, p)
    return s.replace(nb=nb, leader_gap=lg, leader_v=lv)


@pytest.mark.slow
@pytest.mark.parametrize("terminal", [False, True])
def test_timeout_semantics_are_consistent(env_params, terminal):
    """A timeout either truncates with the manoeuvre time unobserved (the default: the learner
    bootstraps from states it has learned) or is terminal with the time observed."""
    env, p = env_params
    p = p.replace(terminal_timeout=terminal)
    s = _quiet_state(env, p, jax.random.PRNGKey(4))
    limit = round(p.manoeuvre_time_limit / p.dt)
    ego = s.ego.replace(  # under RL control, keeping its lane (|offset| = W), one step to go
        phase=jnp.int32(E.RL), x=jnp.float32(200.0), target=jnp.int32(0), steps=jnp.int32(limit - 1)
    )
    s = s.replace(ego=ego)
    before = E.observation(s, p)
    obs, _, _, term, trunc, info = env.step(jax.random.PRNGKey(5), s, jnp.zeros(1), p)
    assert int(info["reason"]) == reward.TIMEOUT
    assert (bool(term), bool(trunc)) == (terminal, not terminal)
    if terminal:
        assert float(before[6]) == pytest.approx((limit - 1) / limit) and float(obs[6]) == 1.0
    else:
        assert float(before[6]) == 0.0 and float(obs[6]) == 0.0


@pytest.mark.slow
@pytest.mark.parametrize(("lane_of_centre", "leader_x"), [(1, 260.0), (0, 230.0)])
def test_own_lane_leader_is_in_the_lane_that_holds_the_egos_centre(
    env_params, lane_of_centre, leader_x
):
    """Origin lane 1 has a vehicle at 260 m, target lane 0 one at 230 m; the ego at 200 m
    follows (and observes) the one in the lane its centre is in, before and after crossing."""
    env, p = env_params
    s = _quiet_state(env, p, jax.random.PRNGKey(3))
    tr = s.traffic
    x = jnp.zeros_like(tr.x).at[1, 0].set(260.0).at[0, 0].set(230.0)
    tr = tr.replace(
        x=x,
        v=jnp.full_like(x, 20.0),
        active=jnp.zeros_like(tr.active).at[1, 0].set(True).at[0, 0].set(True),
    )
    y = (lane_of_centre + 0.45) * p.lane_width  # just inside the lane, near the line
    ego = s.ego.replace(
        phase=jnp.int32(E.RL), x=jnp.float32(200.0), y=jnp.float32(y), target=jnp.int32(0)
    )
    assert int(R.current_lane(ego, p)) == lane_of_centre
    _, leader_gap, leader_v = O.observe_lanes(tr, ego, p)
    assert float(leader_gap) == pytest.approx(leader_x - p.vehicle_length - 200.0)
    obs = E.observation(s.replace(traffic=tr, ego=ego, leader_gap=leader_gap, leader_v=leader_v), p)
    assert float(obs[12]) == pytest.approx((leader_x - p.vehicle_length - 200.0) / 100.0)


@pytest.mark.parametrize("yielding", [True, False])
def test_yielding_lag_opens_the_gap_and_a_non_yielding_one_does_not(env_params, yielding):
    env, p = env_params
    s = _lag_scene(env, p, yielding)

    @jax.jit
    def run(s):
        def body(s, k):
            s = E._advance(k, s, jnp.zeros(1), p, spawn=False)[0]
            return s, s.traffic.x[0, 0] - (s.ego.x - 5.0)

        return jax.lax.scan(body, s, jax.random.split(jax.random.PRNGKey(8), 40))

    s, lag_to_ego_rear = run(s)
    lag_to_ego_rear = np.asarray(lag_to_ego_rear)
    if yielding:
        assert (lag_to_ego_rear < -2.0).all(), "a yielding lag must stay behind the ego"
    else:
        assert lag_to_ego_rear[-1] > 5.0, "a non-yielding lag drives past the ego"


# --- episode rules -------------------------------------------------------------------------


def test_auto_reset_starts_a_new_episode(env_params, rollout, reset_batch):
    env, p = env_params
    obs, state = reset_batch(jax.random.split(jax.random.PRNGKey(9), 8), p)
    (obs, state), out = rollout(obs, state, jax.random.PRNGKey(10), p, steps=600, policy="scripted")
    reason, rl = np.asarray(out["reason"]), np.asarray(out["rl"])
    ended = reason != reward.NONE
    assert (ended.sum(0) >= 2).all(), "every env should finish several episodes"
    # After each env's first end, a fresh manoeuvre starts (traffic kept running).
    first_end = ended.argmax(0)
    rl_start = np.diff(rl.astype(int), axis=0, prepend=0) == 1
    later_start = rl_start & (np.arange(len(rl))[:, None] > first_end[None, :])
    assert later_start.any(0).all()
    # The first RL step of every episode is its first manoeuvre step.
    assert (np.asarray(out["steps"])[rl_start] == 1).all()


@pytest.mark.slow
def test_action_is_refreshed_only_every_k_steps(env_params):
    env, p = env_params
    p = p.replace(k=3)
    s = _lag_scene(env, p, True)
    actions = jnp.linspace(-0.1, 0.1, 9)[:, None]

    @jax.jit
    def run(s):
        def body(s, a):
            _, s, _, _, _, info = env.step(jax.random.PRNGKey(0), s, a, p)
            return s, info["action"]

        return jax.lax.scan(body, s, actions)

    _, executed = run(s)
    want = np.repeat(np.asarray(actions[::3, 0]), 3)
    np.testing.assert_allclose(np.asarray(executed), want, rtol=1e-6)


# --- batching and the reference controller --------------------------------------------------


@pytest.mark.slow
def test_vmap_equals_envs_stepped_one_by_one(env_params):
    env, p = env_params
    keys = jax.random.split(jax.random.PRNGKey(11), 3)
    step_keys = jax.random.split(jax.random.PRNGKey(12), (20, 3))
    actions = jax.random.uniform(jax.random.PRNGKey(13), (20, 3, 1), minval=-1, maxval=1)
    reset1, step1 = jax.jit(env.reset), jax.jit(env.step)
    obs_b, s_b = jax.vmap(env.reset, (0, None))(keys, p)
    vstep = jax.jit(jax.vmap(env.step, (0, 0, 0, None)))
    for t in range(20):
        obs_b, s_b, *_ = vstep(step_keys[t], s_b, actions[t], p)
    for i in range(3):
        obs, s = reset1(keys[i], p)
        for t in range(20):
            obs, s, *_ = step1(step_keys[t, i], s, actions[t, i], p)
        np.testing.assert_allclose(obs, obs_b[i], rtol=1e-5, atol=1e-5)
        for a, b in zip(jax.tree.leaves(s), jax.tree.leaves(s_b), strict=True):
            np.testing.assert_allclose(a, b[i], rtol=1e-5, atol=1e-5)


@pytest.mark.slow
def test_offset_observation_scale_changes_units_not_the_controller(env_params, reset_batch):
    """``offset_obs_scale`` only rescales obs[4] (m per unit): every other column, and the
    scripted controller's action, which reads the offset back in metres, stay the same."""
    env, p = env_params
    keys = jax.random.split(jax.random.PRNGKey(16), 64)
    obs, state = reset_batch(keys, p)
    q = p.replace(offset_obs_scale=1.0)
    obs_q = jax.vmap(E.observation, (0, None))(state, q)
    metres = jax.vmap(R.lateral_offset, (0, None))(state.ego, p)
    np.testing.assert_allclose(obs[:, 4] * p.offset_obs_scale, metres, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(obs_q[:, 4], metres, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(np.delete(obs_q, 4, 1), np.delete(obs, 4, 1))
    moved = obs.at[:, 4].set(jnp.linspace(-1.0, 1.0, 64)).at[:, 2].set(0.05)  # mid-manoeuvre
    moved_q = moved.at[:, 4].multiply(p.offset_obs_scale)
    np.testing.assert_allclose(
        scripted_action(moved_q, q), scripted_action(moved, p), rtol=1e-5, atol=1e-6
    )


@pytest.mark.parametrize("kappa", [0.0, -0.002, 0.002])
def test_scripted_controller_completes_lane_changes(env_params, rollout, reset_batch, kappa):
    """On a straight road and on a 500 m radius bent either way (curvature feed-forward)."""
    env, p = env_params
    p = p.replace(curvature=jnp.float32(kappa))  # traced: the same compiled rollout
    obs, state = reset_batch(jax.random.split(jax.random.PRNGKey(14), 128), p)
    _, out = rollout(obs, state, jax.random.PRNGKey(15), p, steps=1500, policy="scripted")
    reason, rl = np.asarray(out["reason"]), np.asarray(out["rl"])
    ends = np.bincount(reason[rl], minlength=6)
    performed = ends[1:5].sum()
    assert performed >= 300, ends
    assert ends[reward.SUCCESS] / performed >= 0.95, dict(zip(reward.REASONS, ends, strict=True))


@pytest.mark.slow
def test_mirror_signs_reflect_the_observation_the_kinematics_and_keep_the_reward(
    env_params, reset_batch
):
    """``MIRROR_SIGNS`` (``ddpg.mirror``) is the task's reflection y -> -y: the reflected
    ego (lanes swapped, heading, yaw rate and held action negated, on a road curving the
    other way) observes the reflected observation, its kinematics under the negated action
    are the reflected kinematics, and the reward and the end are the same."""
    env, p = env_params
    p = p.replace(curvature=jnp.float32(0.002))
    _, state = reset_batch(jax.random.split(jax.random.PRNGKey(21), 16), p)
    rng = np.random.default_rng(21)
    eg = state.ego.replace(
        psi=jnp.asarray(rng.uniform(-0.1, 0.1, 16), jnp.float32),
        omega=jnp.asarray(rng.uniform(-0.1, 0.1, 16), jnp.float32),
        held=jnp.asarray(rng.uniform(-1, 1, 16), jnp.float32),
        y=jnp.asarray(rng.uniform(0.5, 10.5, 16), jnp.float32),
        target=jnp.asarray(rng.integers(0, 3, 16), state.ego.target.dtype),
    )
    width = p.lanes * p.lane_width
    mirrored = eg.replace(
        y=width - eg.y, psi=-eg.psi, omega=-eg.omega, held=-eg.held, target=p.lanes - 1 - eg.target
    )
    q = p.replace(curvature=-p.curvature)
    obs = jax.vmap(E.observation, (0, None))(state.replace(ego=eg), p)
    obs_m = jax.vmap(E.observation, (0, None))(state.replace(ego=mirrored), q)
    np.testing.assert_allclose(obs_m, obs * np.asarray(E.MIRROR_SIGNS), rtol=1e-5, atol=1e-5)
    assert np.any(obs[:, [2, 3, 4, 5, 7]] != 0, axis=0).all()  # every flipped entry is tested

    a = jnp.asarray(rng.uniform(-0.5, 0.5, 16), jnp.float32)
    # The road's centre line (the Frenet reference) is the axis of the reflection.
    mid = R.reference_y(p)
    step = kinematics.lateral_step(eg.x, eg.y, eg.psi, eg.omega, eg.v, a, p.curvature, p.dt, mid)
    step_m = kinematics.lateral_step(
        eg.x, width - eg.y, -eg.psi, -eg.omega, eg.v, -a, q.curvature, p.dt, mid
    )
    for got, want in zip(step_m, (step[0], width - step[1], -step[2], -step[3]), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-4)

    offset = jnp.asarray(rng.uniform(-4.5, 4.5, 16), jnp.float32)
    collided = jnp.asarray(rng.random(16) < 0.2)
    steps = jnp.asarray(rng.integers(0, 120, 16), jnp.int32)
    terms = paper_terms(eg.omega, a, offset, collided, p)
    terms_m = paper_terms(-eg.omega, -a, -offset, collided, p)
    for got, want in zip(terms_m, terms, strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(
        reward.end_reason(-offset, -eg.psi, -eg.omega, steps, collided, p),
        reward.end_reason(offset, eg.psi, eg.omega, steps, collided, p),
    )


@pytest.mark.slow
@pytest.mark.parametrize("kappa", [-0.002, 0.004])
def test_the_ego_keeps_its_lane_on_a_curve_until_the_rl_phase(env_params, kappa):
    """Before the RL phase the ego holds its lane's line, so the first RL observation is one
    lane width from the target lane's centre, heading along the lane, turning at the lane's
    yaw rate, and the observation reports the road's curvature."""
    from jaxlc.sim.decision import reset_core
    from jaxlc.sim.observation import INDEX, scale

    _, p = env_params
    p = p.replace(curvature=jnp.float32(kappa))
    _, state, out = jax.jit(jax.vmap(lambda k: reset_core(k, p, 3000)))(
        jax.random.split(jax.random.PRNGKey(31), 16)
    )
    assert np.asarray(out["ready"]).all()
    raw = {n: np.asarray(out["obs"][:, INDEX[n]]) * float(scale(n, p)) for n in INDEX}
    np.testing.assert_allclose(np.abs(raw["offset"]), float(p.lane_width), rtol=1e-5)
    np.testing.assert_array_equal(raw["psi"], 0.0)
    d = np.asarray(state.ego.y) - float(R.reference_y(p))
    want = kappa / (1 - kappa * d) * np.asarray(state.ego.v)
    assert np.all(np.abs(want) > 1e-3)  # the ego is moving: its yaw rate is not 0
    np.testing.assert_allclose(raw["omega"], want, rtol=1e-4)
    np.testing.assert_allclose(raw["curvature"], kappa, rtol=1e-6)


@pytest.mark.slow
def test_curvature_drawn_per_episode_lies_in_its_range_and_is_observed():
    """``env.curvature = [min, max]``: each episode draws its road (a leaf of the state only
    then), the observation reports the draw, and the draws spread over the range."""
    lo, hi = -0.004, 0.002
    cfg = config.load(None, ["env.curvature=[-0.004, 0.002]"])
    env, p = jaxlc.make(cfg)
    assert p.curvature_drawn and jaxlc.make()[1].curvature_drawn is False
    assert env.reset(jax.random.PRNGKey(0), jaxlc.make()[1])[1].curvature is None
    from jaxlc.sim.decision import reset_core, step_core

    @jax.jit
    @jax.vmap
    def episodes(key):
        key, s, out = reset_core(key, p, 3000)

        def body(c, _):  # the scripted controller through several episodes
            key, s, obs = c
            key, _, s, o = step_core(key, s, scripted_action(obs, p), p, 3000)
            return (key, s, o["next_obs"]), (o["next_obs"][7], s.curvature)

        return jax.lax.scan(body, (key, s, out["obs"]), None, 120)[1]

    seen, kappa = (np.asarray(a) for a in episodes(jax.random.split(jax.random.PRNGKey(3), 8)))
    np.testing.assert_allclose(seen * 0.01, kappa, rtol=1e-5, atol=1e-9)
    assert kappa.min() >= lo and kappa.max() <= hi
    assert len(np.unique(kappa)) >= 16  # several episodes per env, each its own road
    assert kappa.min() < -0.002 and kappa.max() > 0.0


@pytest.mark.slow
def test_step_ends_are_booleans_whether_params_are_traced_or_constants():
    """``terminated``/``truncated`` are bool arrays also when the params are compiled in as
    Python values (as the trainer does): ``~False`` is -1 in Python, an int."""
    env, p = jaxlc.make()
    _, state = env.reset(jax.random.PRNGKey(0), p)
    closed = jax.jit(lambda k, s, a: env.step(k, s, a, p))
    traced = jax.jit(env.step)
    for out in (closed(jax.random.PRNGKey(1), state, jnp.zeros(1)),
                traced(jax.random.PRNGKey(1), state, jnp.zeros(1), p)):  # fmt: skip
        assert out[3].dtype == jnp.bool_ and out[4].dtype == jnp.bool_


def test_paper_defaults_are_written_once():
    """``configs/default.toml`` holds the config dataclasses' defaults, and ``EnvParams()`` is
    those defaults in SI units: no third copy to drift."""
    from jaxlc import config
    from jaxlc.config import Config, DDPGConfig, EnvConfig

    assert config.load(config.DEFAULT_CONFIG) == config.load(None) == Config()
    assert E.EnvParams() == E.EnvParams.from_config(EnvConfig(), gamma=DDPGConfig().gamma)
    assert jaxlc.make()[1] == E.EnvParams()
    # And a changed config default would move EnvParams with it (units converted).
    faster = E.EnvParams.from_config(EnvConfig(desired_speed_max=150.0))
    assert faster.desired_speed_max == pytest.approx(150.0 / 3.6)


def test_a_command_outside_the_operating_range_is_declined_and_only_then():
    """``env.operating_speed = [min, max]``: a command at a speed outside it, or a gap found
    once the speed has left it, ends the episode as 'declined' (never an RL phase); a command
    inside it goes on as before, and every lane change starts inside it; off by default."""
    assert jaxlc.make()[1].operating_speed == ()
    cfg = config.load(None, ["env.operating_speed=[55.0, 250.0]"])
    env, p = jaxlc.make(cfg)
    keys = jax.random.split(jax.random.PRNGKey(0), 64)
    obs, s = jax.jit(jax.vmap(env.reset, (0, None)))(keys, p)
    step = jax.jit(jax.vmap(env.step, (0, 0, 0, None)))
    declined, taken, started, in_gap = [], [], [], 0
    for k in jax.random.split(jax.random.PRNGKey(1), 400):
        phase = np.asarray(s.ego.phase)
        obs, s, _, _, _, info = step(jax.random.split(k, 64), s, scripted_action(obs, p), p)
        v = np.asarray(s.ego.v) * 3.6  # km/h at the step (kept as a declined episode ends)
        gone = np.asarray(info["reason"]) == reward.DECLINED
        # at the command (entering the gap search) or when the gap is found in it
        assert np.all((phase[gone] == E.CRUISE) | (phase[gone] == E.GAP))
        in_gap += int(np.sum(phase[gone] == E.GAP))
        declined += list(v[gone])
        taken += list(v[np.asarray(E.commanded(s.ego))])
        started += list(v[np.asarray(info["lane_change"])])
    assert len(declined) > 5 and len(taken) > 5 and len(started) > 5 and in_gap > 0
    assert max(declined) < 55.0 <= min(taken) and 55.0 <= min(started)


@pytest.mark.slow
def test_the_lane_relative_yaw_rate_is_0_holding_a_bend_and_the_scripted_law_reads_it(
    env_params,
):
    """``env.yaw_rate_obs = "lane"``: at the first RL observation on a bend, where the ego
    holds its lane's line, obs[3] is 0 where the absolute yaw rate is kappa_d*v, the other
    entries alike; the scripted controller acts the same on either and completes its lane
    changes reading the relative one."""
    from jaxlc.sim.decision import reset_core, step_core
    from jaxlc.sim.observation import INDEX, LAYOUT, meaning
    from jaxlc.sim.reward import NONE, SUCCESS

    _, p = env_params
    p = p.replace(curvature=jnp.float32(0.004))
    q = p.replace(yaw_rate_obs="lane")

    keys = jax.random.split(jax.random.PRNGKey(7), 8)

    @jax.jit
    @jax.vmap
    def episodes(key):  # the lane-relative observation's, driven on by the scripted law
        key, s, out = reset_core(key, q, 3000)

        def body(c, _):
            key, s, obs = c
            key, _, s, o = step_core(key, s, scripted_action(obs, q), q, 3000)
            return (key, s, o["next_obs"]), o["reason_code"]

        return out["obs"], jax.lax.scan(body, (key, s, out["obs"]), None, 150)[1]

    # the absolute observation's first RL step: its reset alone (one program fewer to compile)
    obs_a = np.asarray(jax.jit(jax.vmap(lambda k: reset_core(k, p, 3000)[2]["obs"]))(keys))
    obs_l, ends = (np.asarray(a) for a in episodes(keys))
    i = INDEX["omega"]
    assert np.all(np.abs(obs_a[:, i]) > 1e-3) and np.allclose(obs_l[:, i], 0.0, atol=1e-5)
    np.testing.assert_array_equal(np.delete(obs_a, i, 1), np.delete(obs_l, i, 1))
    np.testing.assert_allclose(scripted_action(obs_a, p), scripted_action(obs_l, q), atol=1e-5)
    assert (
        "relative to the lane" in meaning(LAYOUT[i], q)
        and meaning(LAYOUT[i], p) == "yaw rate, rad/s"
    )
    assert (ends == SUCCESS).sum() >= 8 and np.all((ends == NONE) | (ends == SUCCESS))
