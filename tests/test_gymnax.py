"""The gymnax environment: the gymnasium wrapper's numbers, vmap, the timeout's truncation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

gymnax = pytest.importorskip("gymnax", reason="optional: pip install -e '.[gymnax]'")

import jaxlc  # noqa: E402
import jaxlc.gym as G  # noqa: E402
from jaxlc.gymnax_env import LaneChangeGymnax  # noqa: E402
from jaxlc.sim.reward import REASONS  # noqa: E402

from .test_gym import _policy  # noqa: E402

EPISODES = 4  # kinds 0-3 of _policy: success, timeout, two noisy


@pytest.fixture(scope="module")
def made():
    env, params = jaxlc.make_gymnax()
    return env, params, jax.jit(env.reset), jax.jit(env.step)


def test_it_is_a_gymnax_environment(made):
    env, params, _, _ = made
    assert isinstance(env, gymnax.environments.environment.Environment)
    assert params.max_steps_in_episode == 100  # 10 s of 0.1 s decisions
    assert env.num_actions == 1 and env.action_space(params).shape == (1,)
    low, high = env.observation_space(params).low, env.observation_space(params).high
    assert low.shape == high.shape == (14,) and bool(jnp.all(low < high))


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
        obs, state, reward, done, info = step(key, state, jnp.asarray(action), params)
        assert float(reward) == w_reward
        assert (bool(info["terminated"]), bool(info["truncated"])) == (w_term, w_trunc)
        assert bool(done) == (w_term or w_trunc)
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


def test_vmap_over_envs_equals_one_by_one(made):
    env, params, _, _ = made
    n, steps = 3, 120  # long enough for every env to end a manoeuvre at least once
    keys = jax.random.split(jax.random.PRNGKey(5), n)

    def run(key):
        k_reset, k_run = jax.random.split(key)
        obs, state = env.reset(k_reset, params)

        def body(carry, k):
            obs, state = carry
            k_act, k_step = jax.random.split(k)
            action = env.action_space(params).sample(k_act)
            obs, state, reward, done, _ = env.step(k_step, state, action, params)
            return (obs, state), (obs, reward, done)

        return jax.lax.scan(body, (obs, state), jax.random.split(k_run, steps))[1]

    batched = jax.jit(jax.vmap(run))(keys)
    alone = [jax.jit(run)(k) for k in keys]
    for i in range(n):
        for b, a in zip(batched, alone[i], strict=True):
            np.testing.assert_allclose(np.asarray(b[i]), np.asarray(a), rtol=1e-6, atol=1e-6)
    assert bool(jnp.all(jnp.any(batched[2], axis=1)))


def test_a_timeout_is_truncated_not_terminated(made):
    """Zero yaw acceleration keeps the ego in its lane until the 10 s timeout: the step that
    ends it reports ``truncated`` (and a discount of 1), never ``terminated``."""
    _, params, reset, step = made
    obs, state = reset(jax.random.PRNGKey(3), params)
    zero = jnp.zeros(1)
    for t in range(params.max_steps_in_episode):
        obs, state, reward, done, info = step(jax.random.PRNGKey(100 + t), state, zero, params)
        if bool(done):
            break
    assert REASONS[int(info["reason"])] == "timeout" and t + 1 == params.max_steps_in_episode
    assert bool(info["truncated"]) and not bool(info["terminated"])
    assert float(info["discount"]) == 1.0


def test_the_default_params_are_the_papers():
    env = LaneChangeGymnax()
    assert env.default_params.sim == jaxlc.make()[1]
