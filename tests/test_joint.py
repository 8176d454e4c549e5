"""Lateral and longitudinal control together (``env.longitudinal = "policy"``): the second
action's physics, its reflection, and everything that follows the action's length."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxlc
from jaxlc import config
from jaxlc.learn import replay
from jaxlc.learn.networks import actor_out_dim, make_networks
from jaxlc.sim.controller import scripted_action
from jaxlc.sim.ego import ego_accel
from jaxlc.sim.env import RL, action_dim
from jaxlc.sim.idm import NO_LEADER_GAP
from jaxlc.sim.observation import MIRROR_SIGNS, OBS_DIM

from .conftest import changed_env_keys

JOINT = config.load(config.CONFIG_DIR / "joint.toml")
STEPS = 1500


def _params(longitudinal: str, **env):
    cfg = config.load(overrides=[f"env.longitudinal='{longitudinal}'"])
    return jaxlc.make(dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, **env)))


@pytest.fixture(scope="module")
def rollouts():
    """4 envs, ``STEPS`` steps each, of random yaw accelerations: the paper's ego (``idm``),
    the joint ego with its longitudinal action 0, and with a random one in [-1, 1]."""
    env, p_idm = _params("idm")
    _, p_pol = _params("policy")

    def run(p, long_scale: float):
        def one(key):
            k_reset, k_run = jax.random.split(key)
            _, s = env.reset(k_reset, p)

            def body(s, k):
                k_a, k_l, k_s = jax.random.split(k, 3)
                lat = jax.random.uniform(k_a, (1,), minval=-1.0, maxval=1.0)
                lon = long_scale * jax.random.uniform(k_l, (1,), minval=-1.0, maxval=1.0)
                a = lat if action_dim(p) == 1 else jnp.concatenate([lat, lon])
                _, s2, r, *_, info = env.step(k_s, s, a, p)
                return s2, (s, s2, r, info["action"])

            return jax.lax.scan(body, s, jax.random.split(k_run, STEPS))[1]

        return jax.jit(jax.vmap(one))(jax.random.split(jax.random.key(37), 4))

    return run(p_idm, 0.0), run(p_pol, 0.0), run(p_pol, 1.0), p_pol


def test_a_zero_longitudinal_action_drives_as_the_idm_ego(rollouts) -> None:
    """The policy's acceleration is the IDM's plus its correction: with u = 0 every state, the
    reward and the yaw action are those of the paper's ego bit for bit (the joint state only
    adds the held longitudinal action, 0)."""
    idm, zero, _, _ = rollouts
    (_, s_idm, r_idm, a_idm), (_, s_zero, r_zero, a_zero) = idm, zero
    assert np.asarray(s_zero.ego.phase == RL).any()
    np.testing.assert_array_equal(np.asarray(r_zero), np.asarray(r_idm))
    np.testing.assert_array_equal(np.asarray(a_zero[..., 0]), np.asarray(a_idm))
    np.testing.assert_array_equal(np.asarray(a_zero[..., 1]), 0.0)
    plain = s_zero.replace(ego=s_zero.ego.replace(held_long=None))
    for got, want in zip(jax.tree.leaves(plain), jax.tree.leaves(s_idm), strict=True):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_the_longitudinal_action_moves_the_ego_within_its_bounds(rollouts) -> None:
    """In the RL phase the acceleration is clip(a_IDM + long_acc_bound * u, -b_max, a_max),
    capped so that the ego never passes its desired speed; outside it the IDM's alone."""
    _, _, (before, after, _, action), p = rollouts
    rl = np.asarray(before.ego.phase == RL)
    acc = np.asarray(after.ego.accel)[rl]
    u = np.asarray(action[..., 1])[rl]
    assert np.abs(u).max() > 0.9 and (acc > -float(p.idm_b_max) - 1e-6).all()
    assert (acc <= float(p.idm_a_max) + 1e-6).all()
    v0, v = np.asarray(before.ego.v0)[rl], np.asarray(before.ego.v)[rl]
    v_next = np.asarray(after.ego.v)[rl]
    assert (v_next <= np.maximum(v0, v) + 1e-4).all()  # never accelerated past v0
    # The executed longitudinal action is held for k steps, as the yaw action is; 0 outside RL.
    np.testing.assert_array_equal(np.asarray(action[..., 1])[~rl], 0.0)
    # A braking command brakes: the ego's acceleration falls with u (same state, two actions).
    env = jaxlc.LaneChangeEnv()
    i = np.argwhere(rl)[len(np.argwhere(rl)) // 2]
    s = jax.tree.map(lambda a: a[i[0], i[1]], before)
    k = jax.random.key(0)
    slow = env.step(k, s, jnp.array([0.0, -1.0]), p)[1].ego.accel
    fast = env.step(k, s, jnp.array([0.0, 0.0]), p)[1].ego.accel
    assert float(slow) == pytest.approx(max(float(fast) - 2.0, -float(p.idm_b_max)), abs=1e-5)
    # On a free road, full throttle 0.05 m/s under the desired speed reaches it and no more.
    free = s.replace(
        ego=s.ego.replace(v=s.ego.v0 - 0.05),
        leader_gap=jnp.float32(NO_LEADER_GAP),
        nb=s.nb.replace(has_a1=jnp.bool_(False)),
    )
    assert float(ego_accel(free, p, jnp.float32(1.0))) == pytest.approx(0.05 / p.dt, rel=1e-3)
    assert float(ego_accel(free, p, jnp.float32(0.0))) == float(ego_accel(free, p))


@pytest.mark.slow
def test_the_joint_env_wants_two_action_entries() -> None:
    env, p = _params("policy")
    _, s = env.reset(jax.random.key(0), p)
    assert env.action_space(p).shape == (2,) and action_dim(JOINT.env) == 2
    with pytest.raises(ValueError, match="needs 2 entries"):
        env.step(jax.random.key(1), s, jnp.zeros(1), p)


@pytest.mark.slow
def test_the_symmetric_actor_keeps_the_longitudinal_action_even() -> None:
    """mu(Ms) = (-lateral, +longitudinal): the reflection flips the yaw acceleration and keeps
    the longitudinal one, by construction."""
    actor, _ = make_networks(JOINT.ddpg, 2)
    x = np.zeros((1, OBS_DIM), np.float32)
    params = jax.tree.map(lambda w: w * 3.0, actor.init(jax.random.key(5), x))  # tanh unsaturated
    assert actor_out_dim(params) == 2
    s = np.random.default_rng(5).normal(size=(32, OBS_DIM)).astype(np.float32)
    a = np.asarray(actor.apply(params, s))
    a_m = np.asarray(actor.apply(params, s * np.asarray(MIRROR_SIGNS, np.float32)))
    np.testing.assert_array_equal(a_m, a * np.array([-1.0, 1.0], np.float32))
    assert np.abs(a).max(axis=0).min() > 0.1  # neither entry is trivially 0


@pytest.mark.slow
def test_mirrored_batches_negate_the_lateral_action_alone() -> None:
    mem = replay.init(64, OBS_DIM, 2, 64)
    rows = np.arange(1, 65, dtype=np.float32)
    obs = jnp.asarray(np.tile(rows[:, None], (1, OBS_DIM)))
    act = jnp.asarray(np.stack([rows, 10.0 + rows], -1))
    mem = replay.add(mem, obs, act, rows, obs, jnp.zeros(64), jnp.ones(64, bool))
    key = jax.random.key(2)
    plain = replay.sample(mem, key, 256)
    mirrored = replay.sample(mem, key, 256, MIRROR_SIGNS, (-1.0, 1.0))
    flipped = np.asarray(mirrored["obs"][:, 2]) == -np.asarray(plain["obs"][:, 2])
    assert 0.3 < flipped.mean() < 0.7
    want = np.asarray(plain["action"]) * np.where(flipped[:, None], [-1.0, 1.0], 1.0)
    np.testing.assert_array_equal(np.asarray(mirrored["action"]), want)


def test_the_scripted_controller_leaves_the_longitudinal_to_the_idm() -> None:
    _, p = _params("policy")
    _, p1 = _params("idm")
    obs = jnp.asarray(np.random.default_rng(1).normal(size=(8, OBS_DIM)), jnp.float32)
    a2, a1 = scripted_action(obs, p), scripted_action(obs, p1)
    assert a2.shape == (8, 2) and a1.shape == (8, 1)
    np.testing.assert_array_equal(np.asarray(a2[:, :1]), np.asarray(a1))
    np.testing.assert_array_equal(np.asarray(a2[:, 1]), 0.0)


@pytest.mark.slow
def test_the_wrappers_spaces_follow_the_action() -> None:
    from jaxlc.gym import LaneChangeGymEnv
    from jaxlc.gymnax_env import LaneChangeGymnax, params_for

    _, p = _params("policy")
    gym_env = LaneChangeGymEnv(params=p)
    assert gym_env.action_space.shape == (2,)
    gym_env.reset(seed=0)
    *_, info = gym_env.step(np.array([0.25, -0.5], np.float32))
    np.testing.assert_array_equal(info["action"], [0.25, -0.5])  # both executed, in order
    assert LaneChangeGymnax().action_space(params_for(p)).shape == (2,)
    assert LaneChangeGymnax().action_space().shape == (1,)
    joint = LaneChangeGymnax(params_for(p))
    assert joint.num_actions == 2 and joint.action_space().shape == (2,)
    assert LaneChangeGymnax().num_actions == 1


def test_joint_toml_is_the_default_with_the_joint_keys() -> None:
    """configs/joint.toml spells out every key and differs from the default only in the
    second action and the whole manoeuvre's reward: the rest of the comparison is like for
    like."""
    default = config.Config()
    changed = changed_env_keys("joint.toml", default)
    joint_keys = {"longitudinal", "reward_terms", "w_long_acc", "w_long_jerk", "w_lat_acc"}
    assert changed <= joint_keys | {"w_lat_jerk", "w_headway"}, changed
    assert "longitudinal" in changed
    # the batches its studies trained with: rows reflected at random (the default's pairs
    # came after them, docs/decisions.md)
    assert JOINT.ddpg == dataclasses.replace(default.ddpg, mirror_pairs=False)
    assert all(getattr(JOINT, t) == getattr(default, t) for t in ("train", "grid"))
