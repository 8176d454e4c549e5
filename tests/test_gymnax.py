"""The gymnax environment: gymnax 1.x's contract (its wrappers run on it), the five-value
adapter, the gymnasium wrapper's numbers, vmap, the timeout's truncation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

gymnax = pytest.importorskip("gymnax", reason="optional: pip install -e '.[gymnax]'")

from gymnax.wrappers.purerl import FlattenObservationWrapper, LogWrapper  # noqa: E402

import jaxlc  # noqa: E402
import jaxlc.gym as G  # noqa: E402
from jaxlc.gymnax_env import FiveValueAdapter, LaneChangeGymnax  # noqa: E402
from jaxlc.sim.controller import scripted_action  # noqa: E402
from jaxlc.sim.reward import REASONS  # noqa: E402

from .test_gym import _policy  # noqa: E402

EPISODES = 4  # kinds 0-3 of _policy: success, timeout, two noisy
# The wrapped rollout: envs of three kinds (scripted: success; zero action: a timeout every
# 100 decisions; random actions) for long enough that each kind ends at least two episodes.
ROLLOUT_ENVS, ROLLOUT_STEPS = 6, 210


@pytest.fixture(scope="module")
def made():
    env, params = jaxlc.make_gymnax()
    # reset and step are jitted already (gymnax's decorator); calling them as they are shares
    # their compiled programs with FiveValueAdapter, which calls env.step.
    return env, params, env.reset, env.step


@pytest.mark.slow
def test_it_is_a_gymnax_environment(made):
    env, params, reset, step = made
    assert isinstance(env, gymnax.environments.environment.Environment)
    assert params.max_steps_in_episode == 100  # 10 s of 0.1 s decisions
    assert env.num_actions == 1 and env.action_space(params).shape == (1,)
    low, high = env.observation_space(params).low, env.observation_space(params).high
    assert low.shape == high.shape == (14,) and bool(jnp.all(low < high))
    obs, state = reset(jax.random.PRNGKey(0), params)
    out = step(jax.random.PRNGKey(1), state, jnp.zeros(1), params)
    assert len(out) == 6  # gymnax 1.x: obs, state, reward, terminated, truncated, info
    assert {"terminated", "truncated", "final_observation"} <= set(out[5])


def test_step_is_step_env_and_is_truncated(made):
    """``step`` is gymnax's composition: ``step_env`` with the key's second half, then
    ``is_truncated`` on the state it produced, then the next manoeuvre on an end. Checked
    on the step that ends a manoeuvre by the 10 s timeout (zero action) and on one before."""
    env, params, reset, step = made
    step_env = jax.jit(env.step_env)
    _, state = reset(jax.random.PRNGKey(3), params)
    zero = jnp.zeros(1)
    for t in range(params.max_steps_in_episode):
        key = jax.random.PRNGKey(100 + t)
        obs_st, state_st, r_st, term_st, _ = step_env(jax.random.split(key)[1], state, zero, params)
        obs, nxt, reward, terminated, truncated, info = step(key, state, zero, params)
        np.testing.assert_array_equal(np.asarray(info["final_observation"]), np.asarray(obs_st))
        assert float(reward) == float(r_st) and bool(terminated) == bool(term_st)
        assert bool(truncated) == bool(env.is_truncated(state_st, params))
        assert int(state_st.time) == t + 1
        if t < params.max_steps_in_episode - 1:  # the manoeuvre goes on: obs is the step's own
            assert not bool(truncated) and int(nxt.time) == t + 1
            np.testing.assert_array_equal(np.asarray(obs), np.asarray(obs_st))
        state = nxt
    assert bool(truncated) and not bool(terminated) and int(nxt.time) == 0
    assert not np.array_equal(np.asarray(obs), np.asarray(obs_st))  # the next ego's first


@pytest.fixture(scope="module")
def rollout(made):
    """``(run, keys, out)``: ``run(key, kind)`` rolls out ``LogWrapper(FlattenObservationWrapper
    (env))`` for one env; ``out`` is it vmapped over ``keys``, compiled once."""
    env, params, _, _ = made
    wrapped = LogWrapper(FlattenObservationWrapper(env))

    def act(kind: jax.Array, obs: jax.Array, key: jax.Array) -> jax.Array:
        noise = jax.random.uniform(key, (1,), minval=-1.0, maxval=1.0)
        return jnp.where(kind == 0, scripted_action(obs, params.sim), (kind == 2) * noise)

    def run(key: jax.Array, kind: jax.Array):
        k_reset, k_run = jax.random.split(key)
        obs, state = wrapped.reset(k_reset, params)

        def body(carry, k):
            obs, state = carry
            k_act, k_step = jax.random.split(k)
            obs, state, reward, term, trunc, info = wrapped.step(
                k_step, state, act(kind, obs, k_act), params
            )
            return (obs, state), (obs, reward, term, trunc, info)

        return jax.lax.scan(body, (obs, state), jax.random.split(k_run, ROLLOUT_STEPS))[1]

    keys = jax.random.split(jax.random.PRNGKey(7), ROLLOUT_ENVS)
    kinds = jnp.arange(ROLLOUT_ENVS) % 3
    return run, keys, jax.device_get(jax.jit(jax.vmap(run))(keys, kinds))


def test_gymnax_log_and_flatten_wrappers_log_the_envs_own_returns(rollout):
    obs, reward, term, trunc, info = rollout[2]
    done = term | trunc
    assert obs.shape == (ROLLOUT_ENVS, ROLLOUT_STEPS, 14)
    assert info["final_observation"].shape == obs.shape
    np.testing.assert_array_equal(info["returned_episode"], done)
    assert done.any(axis=1).all()  # every env ended at least one episode
    logged_return = info["returned_episode_returns"]
    logged_length = info["returned_episode_lengths"]
    # At each end, LogWrapper's return and length are the env's own count of the episode...
    np.testing.assert_array_equal(logged_return[done], info["episode_return"][done])
    np.testing.assert_array_equal(logged_length[done], info["episode_steps"][done])
    # ... and the sum of the rewards the rollout saw since the previous end.
    for e in range(ROLLOUT_ENVS):
        ends = np.flatnonzero(done[e])
        for start, end in zip(np.r_[0, ends[:-1] + 1], ends, strict=True):
            seen = reward[e, start : end + 1]
            np.testing.assert_allclose(logged_return[e, end], seen.sum(), rtol=1e-5)
            assert logged_length[e, end] == len(seen)
    reasons = {REASONS[c] for c in info["reason"][done]}
    assert {"success", "timeout", "out_of_bounds"} <= reasons, reasons
    timeout = info["reason"] == REASONS.index("timeout")
    assert (trunc == timeout).all() and not (term & trunc).any()
    assert (logged_length[timeout] == 100).all()


def test_the_five_value_adapter(made):
    """``FiveValueAdapter``: gymnax 0.0.x's ``obs, state, reward, done, info`` with ``done =
    terminated | truncated``, the same numbers and ``info``; over this env and over another
    gymnax 1.x env (CartPole, cheap to compile)."""
    env, params, reset, step = made
    adapted = FiveValueAdapter(env)
    assert adapted.default_params == env.default_params and adapted.num_actions == 1
    obs, state = reset(jax.random.PRNGKey(3), params)
    ended = 0
    for t in range(params.max_steps_in_episode):
        key, action = jax.random.PRNGKey(100 + t), jnp.zeros(1)
        six = step(key, state, action, params)
        five = adapted.step(key, state, action, params)
        assert len(five) == 5
        np.testing.assert_array_equal(np.asarray(five[0]), np.asarray(six[0]))
        assert float(five[2]) == float(six[2])
        assert bool(five[3]) == bool(six[3] | six[4]) == bool(five[4]["truncated"])
        ended += bool(five[3])
        state = six[1]
    assert ended == 1  # the timeout on the 100th decision
    cartpole, cp_params = gymnax.make("CartPole-v1")
    cp = FiveValueAdapter(cartpole)
    _, cp_state = cp.reset(jax.random.PRNGKey(0), cp_params)
    dones = []
    for t in range(60):  # pushing one way topples the pole well before 60 steps
        _, cp_state, _, done, info = cp.step(jax.random.PRNGKey(t), cp_state, 1, cp_params)
        dones.append(bool(done))
        assert bool(done) == bool(info["terminated"] | info["truncated"])
    assert any(dones)


@pytest.mark.slow
def test_same_numbers_as_the_gymnasium_wrapper(made):
    """Fed the keys the wrapper uses and the same actions, the gymnax env returns the
    wrapper's observations, rewards and ends; on an end, its ``obs`` is the next manoeuvre's
    first (the wrapper's next ``reset()``) and the ended one is ``final_observation``."""
    _, params, reset, step = made
    wrapper = G.LaneChangeGymEnv(params=params.sim)
    w_obs, _ = wrapper.reset(seed=11)
    obs, state = reset(jax.random.PRNGKey(11), params)
    np.testing.assert_array_equal(np.asarray(obs), w_obs)
    episode, t, reasons = 0, 0, set()
    while episode < EPISODES:
        action = _policy(w_obs, params.sim, episode, t)
        key = wrapper._key  # the key the wrapper's next step splits
        w_next, w_reward, w_term, w_trunc, w_info = wrapper.step(action)
        obs, state, reward, terminated, truncated, info = step(
            key, state, jnp.asarray(action), params
        )
        assert float(reward) == w_reward
        assert (bool(terminated), bool(truncated)) == (w_term, w_trunc)
        assert (bool(info["terminated"]), bool(info["truncated"])) == (w_term, w_trunc)
        assert REASONS[int(info["reason"])] == w_info["reason"]
        np.testing.assert_array_equal(np.asarray(info["final_observation"]), w_next)
        t += 1
        if w_term or w_trunc:
            reasons.add(w_info["reason"])
            w_next, _ = wrapper.reset()  # the next ego on the same road
            episode, t = episode + 1, 0
            assert int(state.time) == 0
        else:
            assert int(state.time) == t
        np.testing.assert_array_equal(np.asarray(obs), w_next)
        w_obs = w_next
    assert "success" in reasons and "timeout" in reasons  # both kinds of end were compared


def test_vmap_over_envs_equals_one_by_one(rollout):
    """The wrapped rollout, vmapped over six envs, equals it run for one env at a time (one
    env of each kind)."""
    run, keys, batched = rollout
    one = jax.jit(run)
    for i in range(3):
        alone = jax.device_get(one(keys[i], jnp.int32(i % 3)))
        for b, a in zip(jax.tree.leaves(batched), jax.tree.leaves(alone), strict=True):
            np.testing.assert_allclose(b[i], a, rtol=1e-6, atol=1e-6)


def test_a_timeout_is_truncated_not_terminated(made):
    """Zero yaw acceleration keeps the ego in its lane until the 10 s timeout: the step that
    ends it reports ``truncated`` (and a discount of 1), never ``terminated``."""
    _, params, reset, step = made
    obs, state = reset(jax.random.PRNGKey(3), params)
    zero = jnp.zeros(1)
    for t in range(params.max_steps_in_episode):
        obs, state, reward, terminated, truncated, info = step(
            jax.random.PRNGKey(100 + t), state, zero, params
        )
        if bool(terminated | truncated):
            break
    assert REASONS[int(info["reason"])] == "timeout" and t + 1 == params.max_steps_in_episode
    assert bool(truncated) and not bool(terminated)
    assert float(info["discount"]) == 1.0


def test_the_default_params_are_the_papers():
    env = LaneChangeGymnax()
    assert env.default_params.sim == jaxlc.make()[1]
