"""The gymnasium wrappers: API conformance, replay against the functional API, vector env,
observation bounds, rendering, and the comparison benchmarks in tiny mode."""

from __future__ import annotations

import math
import warnings
from functools import partial

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import jaxlc
import jaxlc.gym as G
import jaxlc.sim.observation as O
from jaxlc.sim.controller import scripted_action
from jaxlc.sim.env import RL, LaneChangeEnv
from jaxlc.sim.reward import REASONS

N_VEC = 4  # one batch size for every vector test, so the vmapped program compiles once


def _policy(obs: np.ndarray, params: jaxlc.EnvParams, episode: int, t: int) -> np.ndarray:
    """Deterministic actions that give every kind of ending: the scripted controller (success),
    zero (the ego keeps its lane: timeout, a truncation), and noisy versions (out of bounds)."""
    kind = episode % 4
    if kind == 1:
        return np.zeros(1, np.float32)
    a = np.asarray(scripted_action(jnp.asarray(obs), params), np.float32)
    if kind >= 2:
        noise = np.random.default_rng(1000 * episode + t).normal(0.0, 0.6, 1)
        a = np.clip(a + noise, -1, 1).astype(np.float32)
    return a


@pytest.fixture(scope="module")
def params() -> jaxlc.EnvParams:
    return jaxlc.make()[1]


@pytest.mark.slow
def test_check_env_passes_with_warnings_as_errors():
    env = gym.make(G.ENV_ID, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any gymnasium checker warning fails the test
        check_env(env.unwrapped)
    env.close()


def test_registered_ids_make_the_wrappers():
    env = gym.make(G.ENV_ID)
    assert isinstance(env.unwrapped, G.LaneChangeGymEnv)
    envs = gym.make_vec(G.ENV_ID, num_envs=N_VEC)
    assert isinstance(envs, G.LaneChangeVectorEnv) and envs.num_envs == N_VEC
    assert envs.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert envs.single_observation_space == env.observation_space


def _wrapper_rollout(seed: int, episodes: int, params: jaxlc.EnvParams) -> list[dict]:
    env = G.LaneChangeGymEnv(params=params)
    obs, info = env.reset(seed=seed)
    rows, episode, t = [], 0, 0
    while episode < episodes:
        action = _policy(obs, params, episode, t)
        nxt, reward, term, trunc, step_info = env.step(action)
        rows.append({"obs": obs, "action": action, "reward": reward, "term": term,
                     "trunc": trunc, "next_obs": nxt, "info": step_info})  # fmt: skip
        obs, t = nxt, t + 1
        if term or trunc:
            obs, _ = env.reset()
            episode, t = episode + 1, 0
    return rows


def _functional_rollout(seed: int, episodes: int, params: jaxlc.EnvParams) -> list[dict]:
    """The wrapper's semantics written out with the functional API: PRNGKey(seed), one split
    for reset, then one split per env.step; zero actions outside the RL phase."""
    env = LaneChangeEnv()
    step = jax.jit(partial(env.step, params=params))
    reset = jax.jit(partial(env.reset, params=params))
    key = jax.random.PRNGKey(seed)
    key, k = jax.random.split(key)
    _, state = reset(k)

    def to_rl(key, state):
        obs = None
        while int(state.ego.phase) != RL:
            key, k = jax.random.split(key)
            obs, state, *_ = step(k, state, jnp.zeros(1))
        return key, state, np.asarray(obs)

    key, state, obs = to_rl(key, state)
    rows, episode, t = [], 0, 0
    while episode < episodes:
        action = _policy(obs, params, episode, t)
        key, k = jax.random.split(key)
        nxt, state, reward, term, trunc, info = step(k, state, jnp.asarray(action))
        assert bool(info["rl_step"])
        rows.append({"obs": obs, "action": action, "reward": float(reward), "term": bool(term),
                     "trunc": bool(trunc), "next_obs": np.asarray(nxt),
                     "reason": REASONS[int(info["reason"])]})  # fmt: skip
        obs, t = np.asarray(nxt), t + 1
        if term or trunc:
            key, state, obs = to_rl(key, state)
            episode, t = episode + 1, 0
    return rows


@pytest.mark.slow
def test_rollout_equals_functional_api_and_is_reproducible(params):
    episodes = 5
    a = _wrapper_rollout(7, episodes, params)
    b = _wrapper_rollout(7, episodes, params)  # a second instance, same seed and actions
    f = _functional_rollout(7, episodes, params)
    assert len(a) == len(b) == len(f)
    # Bit-for-bit: the wrapper runs the same jitted env.step, with the same keys.
    for ra, rb, rf in zip(a, b, f, strict=True):
        for name in ("obs", "next_obs"):
            np.testing.assert_array_equal(ra[name], rb[name])
            np.testing.assert_array_equal(ra[name], rf[name])
        assert ra["reward"] == rb["reward"] == rf["reward"]
        assert (ra["term"], ra["trunc"]) == (rb["term"], rb["trunc"]) == (rf["term"], rf["trunc"])
        assert ra["info"]["reason"] == rf["reason"]
        i = ra["info"]
        assert i["r_s"] + i["r_e"] + i["r_d"] == pytest.approx(ra["reward"], rel=1e-5, abs=1e-4)
    ends = [r["info"]["reason"] for r in a if r["term"] or r["trunc"]]
    assert len(ends) == episodes
    # The policy mix produces successes and timeouts; a timeout truncates, the rest terminate.
    assert "success" in ends and "timeout" in ends
    for r in a:
        if r["term"] or r["trunc"]:
            assert r["trunc"] == (r["info"]["reason"] == "timeout")
        else:
            assert r["info"]["reason"] == "none"


@pytest.mark.slow
def test_vector_env_equals_single_envs(params):
    """LaneChangeVectorEnv against gymnasium's SyncVectorEnv of single wrappers, both in
    same-step autoreset and both seeding sub-env i with seed + i."""
    vec = G.LaneChangeVectorEnv(N_VEC, params=params)
    ref = SyncVectorEnv(
        [lambda: G.LaneChangeGymEnv(params=params) for _ in range(N_VEC)],
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    obs_v, _ = vec.reset(seed=3)
    obs_r, _ = ref.reset(seed=3)
    np.testing.assert_array_equal(obs_v, obs_r)
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(120):
        act = np.asarray(scripted_action(jnp.asarray(obs_v), params))
        act = np.clip(act + rng.normal(0, 0.3, act.shape), -1, 1).astype(np.float32)
        obs_v, rew_v, term_v, trunc_v, info_v = vec.step(act)
        obs_r, rew_r, term_r, trunc_r, info_r = ref.step(act)
        np.testing.assert_array_equal(obs_v, obs_r)
        np.testing.assert_array_equal(rew_v, rew_r)
        np.testing.assert_array_equal(term_v, term_r)
        np.testing.assert_array_equal(trunc_v, trunc_r)
        done = term_v | trunc_v
        np.testing.assert_array_equal(info_v["_final_obs"], done)
        for i in np.nonzero(done)[0]:
            np.testing.assert_array_equal(info_v["final_obs"][i], info_r["final_obs"][i])
            assert info_v["reason"][i] == info_r["final_info"]["reason"][i]
        ended += int(done.sum())
    assert ended >= N_VEC  # autoreset really happened


@pytest.mark.slow
def test_every_observation_lies_in_the_space(params):
    """Random, scripted and non-finite actions: every returned and final observation is
    inside the documented finite bounds."""
    vec = G.LaneChangeVectorEnv(N_VEC, params=params)
    space = vec.single_observation_space
    assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))
    obs, _ = vec.reset(seed=11)
    rng = np.random.default_rng(1)
    for t in range(300):
        mode = (t // 50) % 3
        if mode == 0:
            act = rng.uniform(-1, 1, (N_VEC, 1))
        elif mode == 1:
            act = np.asarray(scripted_action(jnp.asarray(obs), params))
        else:
            act = rng.choice([np.nan, np.inf, -np.inf, 1e30, 0.0, 1.0], (N_VEC, 1))
        obs, _, term, trunc, info = vec.step(act.astype(np.float32))
        for row in (*obs, *info["final_obs"][term | trunc]):
            assert row in space, (row, space.low, space.high)


def test_step_and_render_need_a_reset():
    env = G.LaneChangeGymEnv(render_mode="rgb_array")
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(1, np.float32))
    with pytest.raises(gym.error.ResetNeeded):
        env.render()
    env.reset(seed=0)
    term = trunc = False
    while not (term or trunc):
        _, _, term, trunc, _ = env.step(np.ones(1, np.float32))  # steers off the road
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(1, np.float32))


@pytest.mark.slow
def test_render_draws_the_scene(params):
    env = G.LaneChangeGymEnv(params=params, render_mode="rgb_array")
    env.reset(seed=5)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    red = (frame[..., 0] > 200) & (frame[..., 1] < 80) & (frame[..., 2] < 80)
    blue = (frame[..., 2] > 200) & (frame[..., 0] < 100)
    assert 100 < red.sum() < 1000  # the ego: 5 m x 1.8 m at 8 px/m = 576 px
    assert blue.sum() > 0  # traffic around it
    # After the last step of a manoeuvre the terminal scene is still drawn.
    term = trunc = False
    while not (term or trunc):
        _, _, term, trunc, _ = env.step(np.ones(1, np.float32))
    assert env.render().shape == frame.shape
    vec = G.LaneChangeVectorEnv(N_VEC, params=params, render_mode="rgb_array")
    vec.reset(seed=0)
    frames = vec.render()
    assert len(frames) == N_VEC and all(f.shape == frame.shape for f in frames)


@pytest.mark.slow
@pytest.mark.parametrize("kappa", [0.004, -0.004])
def test_render_bends_a_curved_road_by_its_sagitta(params, kappa):
    """Drawn on a curve, the road's edge x metres from the window's centre lies off its edge
    at the centre by the arc's sagitta, x^2 * kappa / 2, toward the bend; the ego is still
    drawn."""
    view, px = 120.0, 8.0
    straight = G.render_frame(_reset_state(params), params, view_m=view, px_per_m=px)
    curved = params.replace(curvature=kappa)
    frame = G.render_frame(_reset_state(curved), curved, view_m=view, px_per_m=px)
    assert frame.shape[1] == straight.shape[1] and frame.shape[0] > straight.shape[0]
    verge = np.all(frame == (96, 140, 80), axis=-1)
    x_off = 0.375 * view  # m from the window's centre: a column clear of the window's end
    cols = (round((0.5 * view - x_off) * px), frame.shape[1] // 2)
    top_edge, top_centre = (int(np.nonzero(~verge[10:, c])[0].min()) for c in cols)
    sagitta_px = x_off**2 * abs(kappa) / 2 * px  # 32 px at kappa = 0.004
    # kappa > 0 bends to the left, up the picture: the road rises away from the centre.
    assert (top_centre - top_edge) * np.sign(kappa) == pytest.approx(sagitta_px, abs=4)
    red = (frame[..., 0] > 200) & (frame[..., 1] < 80) & (frame[..., 2] < 80)
    assert 100 < red.sum() < 1000


def _reset_state(params):
    env = G.LaneChangeGymEnv(params=params)
    env.reset(seed=5)
    return env._state


@pytest.mark.slow
def test_observation_bounds_follow_the_params(params):
    low, high = O.bounds(params)
    assert low.shape == high.shape == (14,) and np.all(low < high)
    wider = params.replace(manoeuvre_time_limit=20.0)
    assert O.bounds(wider)[1][3] > high[3]  # omega can grow for longer
    curved = params.replace(curvature=0.002)
    c_low, c_high = O.bounds(curved)
    assert np.all(np.isfinite(c_high)) and np.all(c_high >= high)  # the ego holds its lane
    assert c_high[2] > high[2] and c_high[3] > high[3]  # the lane's yaw rate turns the ego
    curved_env = G.LaneChangeGymEnv(params=curved)
    obs, _ = curved_env.reset(seed=5)
    for _ in range(60):  # the scripted controller's lane change stays inside the space
        assert obs in curved_env.observation_space, obs
        obs, _, term, trunc, _ = curved_env.step(
            np.asarray(scripted_action(jnp.asarray(obs), curved), np.float32)
        )
        if term or trunc:
            break
    assert obs in curved_env.observation_space, obs
    for scale in (1.0, 7.4):  # the offset's bound is in the env's units, whatever they are
        scaled = params.replace(offset_obs_scale=scale)
        env = G.LaneChangeGymEnv(params=scaled)
        obs, _ = env.reset(seed=3)  # the first RL observation: |offset| = one lane width
        assert abs(obs[4]) == pytest.approx(float(params.lane_width) / scale, rel=1e-5)
        assert obs in env.observation_space, (obs, env.observation_space.high)


def _positive(x: float) -> bool:
    return math.isfinite(x) and x > 0


def test_the_road_frame_maps_to_the_world_and_back():
    """``render``'s mapping, on its own: the identity on a straight road; on a bend a point
    on the reference line lies on the circle about (0, 1/kappa), and the inverse returns it."""
    from jaxlc.sim import render

    s, d = np.linspace(-60.0, 60.0, 7), np.linspace(-3.5, 3.5, 7)
    straight = render.road_to_world(s, d, 0.0)
    assert np.array_equal(straight[0], s) and np.array_equal(straight[1], d)
    for kappa in (0.004, -0.01):
        x, y = render.road_to_world(s, d, kappa)
        back = render.world_to_road(x, y, kappa)
        np.testing.assert_allclose(back, (s, d), atol=1e-9)
        on_line = render.road_to_world(s, np.zeros_like(s), kappa)
        np.testing.assert_allclose(np.hypot(on_line[0], on_line[1] - 1 / kappa), 1 / abs(kappa))
