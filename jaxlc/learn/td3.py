"""TD3 (Fujimoto et al. 2018), a learner beside the paper's DDPG (``ddpg.learner = "td3"``).

Twin critics regress on the smaller target Q, the target action is smoothed with clipped noise
drawn from the update's key, and the actor and both targets move only every
``td3_policy_delay``-th update; the critic loss is the sum of the twins' losses. Everything
else is DDPG's (``jaxlc.learn.ddpg``): the learner state, the per-model ``Hyper``, the Adam
and soft-target step, exploration and the per-sample critic loss, so the grid trainer runs
either through the same interface (``jaxlc.learn.learners``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxlc.config import DDPGConfig
from jaxlc.learn import tree
from jaxlc.learn.ddpg import (
    Hyper,
    Learner,
    Params,
    apply_gradients,
    critic_error,
    explore,
    fresh,
)
from jaxlc.learn.networks import batch_actor, make_networks

__all__ = ["Hyper", "Learner", "explore", "init_learner", "update"]


def init_learner(key: jax.Array, obs_dim: int, cfg: DDPGConfig, act_dim: int = 1) -> Learner:
    """Fresh networks as DDPG's, but twin critics: every critic leaf has a leading axis of 2."""
    actor, critic = make_networks(cfg, act_dim)
    k_actor, k_critic = jax.random.split(key)
    obs = jnp.zeros((1, obs_dim), jnp.float32)
    act = jnp.zeros((1, act_dim), jnp.float32)
    twins = jax.vmap(lambda k: critic.init(k, obs, act))(jax.random.split(k_critic))
    return fresh(actor.init(k_actor, obs), twins)


def update(
    learner: Learner,
    batch: dict[str, jax.Array],
    hyper: Hyper,
    cfg: DDPGConfig,
    key: jax.Array | None = None,
) -> tuple[Learner, dict[str, jax.Array]]:
    """One TD3 update (module docstring); ``key`` draws the target-action noise. Metrics as
    ``ddpg.update``'s (the critic loss is the twins' sum, mean_q both twins' mean)."""
    if key is None:
        raise ValueError("td3.update: TD3 needs a key for its target-action noise")
    actor, critic = make_networks(cfg, batch["action"].shape[-1])
    obs, act, next_obs = batch["obs"], batch["action"], batch["next_obs"]
    policy = batch_actor(actor, cfg)  # (batch, obs_dim) -> (batch, act_dim)
    q_twins = jax.vmap(critic.apply, (0, None, None))  # (2, batch) from (2, ...) params

    next_act = policy(learner.actor_target, next_obs)
    noise = cfg.td3_target_noise * jax.random.normal(key, next_act.shape, next_act.dtype)
    clip = cfg.td3_target_clip
    next_act = jnp.clip(next_act + jnp.clip(noise, -clip, clip), -1.0, 1.0)
    next_q = jnp.min(q_twins(learner.critic_target, next_obs, next_act), axis=0)
    y = batch["reward"] + cfg.gamma * (1.0 - batch["terminated"]) * next_q  # (batch,)

    def critic_loss(params: Params) -> tuple[jax.Array, jax.Array]:
        q = q_twins(params, obs, act)  # (2, batch)
        return jnp.sum(jnp.mean(critic_error(q, y, cfg), axis=-1)), q

    first = jax.tree.map(lambda x: x[0], learner.critic)  # the actor ascends the first twin

    def actor_loss(params: Params) -> jax.Array:
        return -jnp.mean(critic.apply(first, obs, policy(params, obs)))

    (c_loss, q), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(learner.critic)
    a_loss, a_grads = jax.value_and_grad(actor_loss)(learner.actor)
    stepped = apply_gradients(learner, c_grads, a_grads, hyper, cfg.tau)
    # the actor and both targets move every td3_policy_delay-th update only
    slow = ("actor", "actor_opt", "actor_target", "critic_target")
    delayed = learner.step % cfg.td3_policy_delay == 0
    kept = tree.where(
        delayed,
        {n: getattr(stepped, n) for n in slow},
        {n: getattr(learner, n) for n in slow},
    )
    new = stepped.replace(**kept)
    return new, {"critic_loss": c_loss, "actor_loss": a_loss, "mean_q": jnp.mean(q)}
