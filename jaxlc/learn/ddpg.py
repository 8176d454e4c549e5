"""DDPG learner, paper eqs. (4)-(7): pure functions over a ``Learner`` pytree.

Hyperparameters that differ between models of the grid (learning rates, exploration sigma) live
in ``Hyper`` as traced scalars so that ``jax.vmap`` runs every model in one program; the static
``DDPGConfig`` fixes shapes and the constants shared by the grid (hidden sizes, gamma, tau).
Gradients are plain ``jax.grad`` (docs/decisions.md, "DDPG's gradients").
"""

from __future__ import annotations

import flax.struct
import jax
import jax.numpy as jnp
import optax

from jaxlc.config import DDPGConfig
from jaxlc.learn.networks import batch_actor, make_networks
from jaxlc.sim.observation import INDEX

Params = dict


@flax.struct.dataclass
class Hyper:
    """Per-model hyperparameters, each a () float32 (a (models,) array under vmap)."""

    actor_lr: jax.Array
    critic_lr: jax.Array
    noise_sigma: jax.Array

    @staticmethod
    def from_config(cfg: DDPGConfig) -> Hyper:
        return Hyper(
            actor_lr=jnp.float32(cfg.actor_lr),
            critic_lr=jnp.float32(cfg.critic_lr),
            noise_sigma=jnp.float32(cfg.noise_sigma),
        )


@flax.struct.dataclass
class Learner:
    """Online and target params (flax pytrees), Adam states, and the update count."""

    actor: Params
    critic: Params
    actor_target: Params
    critic_target: Params
    actor_opt: optax.OptState
    critic_opt: optax.OptState
    step: jax.Array  # () int32, updates done


# Adam without its learning rate: the rate is a traced per-model value applied in ``update``.
_adam = optax.scale_by_adam()


def init_learner(key: jax.Array, obs_dim: int, cfg: DDPGConfig, act_dim: int = 1) -> Learner:
    """Fresh online networks, targets equal to them, zeroed Adam moments."""
    actor, critic = make_networks(cfg, act_dim)
    k_actor, k_critic = jax.random.split(key)
    obs = jnp.zeros((1, obs_dim), jnp.float32)
    act = jnp.zeros((1, act_dim), jnp.float32)
    actor_params = actor.init(k_actor, obs)
    return fresh(actor_params, critic.init(k_critic, obs, act))


def fresh(actor_params: Params, critic_params: Params) -> Learner:
    """A learner from initial params: targets equal to them, zeroed Adam moments."""
    return Learner(
        actor=actor_params,
        critic=critic_params,
        actor_target=jax.tree.map(jnp.copy, actor_params),
        critic_target=jax.tree.map(jnp.copy, critic_params),
        actor_opt=_adam.init(actor_params),
        critic_opt=_adam.init(critic_params),
        step=jnp.zeros((), jnp.int32),
    )


def optimizer_step(
    params: Params, grads: Params, opt: optax.OptState, lr: jax.Array, target: Params, tau: float
) -> tuple[Params, optax.OptState, Params]:
    """One Adam step at the traced rate ``lr``, then the soft target update, eqs. (6)/(7)."""
    updates, opt = _adam.update(grads, opt, params)
    params = jax.tree.map(lambda p, u: p - lr * u, params, updates)
    target = jax.tree.map(lambda t, p: t + tau * (p - t), target, params)
    return params, opt, target


def critic_error(q: jax.Array, y: jax.Array, cfg: DDPGConfig) -> jax.Array:
    """Per-sample critic loss: eq. (4)'s squared TD error, replaced beyond
    ``cfg.huber_delta`` by the Huber loss's linear branch (the default; 0 keeps the square:
    docs/decisions.md) so that outlying TD errors (the cliff of eq. (11)) pull boundedly."""
    if cfg.huber_delta > 0:
        return 2.0 * optax.losses.huber_loss(q, y, delta=cfg.huber_delta)  # = (y - q)^2 inside
    return jnp.square(y - q)


def update(
    learner: Learner,
    batch: dict[str, jax.Array],
    hyper: Hyper,
    cfg: DDPGConfig,
    key: jax.Array | None = None,
) -> tuple[Learner, dict[str, jax.Array]]:
    """One DDPG update from a batch (keys and shapes as ``replay.sample`` returns them).

    Critic: minimise eq. (4), y = r + gamma (1 - terminated) Q'(s', mu'(s')), per sample
    ``critic_error``; actor: ascend eq. (5); targets: eqs. (6)/(7) after the Adam steps. With
    ``cfg.held_aware`` (``batch["refresh"]``) the target's next action is mu'(s') only where s'
    refreshes the held action, the held one elsewhere, and eq. (5) averages over the states
    that refresh it (docs/decisions.md).
    Metrics: critic_loss, actor_loss (= -mean Q(s, mu(s))), mean_q (= mean Q(s, a)), each
    ``()``. ``key`` is unused (DDPG's update draws nothing); the learner interface passes it.

    Both gradients use the params from before this step, as reference implementations do
    (OpenAI baselines' DDPG), so the critic and actor passes are independent and XLA can
    overlap them. The actor's gradient differentiates only the actor's params: the critic's
    weight gradients are never formed on that pass.
    """
    del key
    actor, critic = make_networks(cfg, batch["action"].shape[-1])
    obs, act, next_obs = batch["obs"], batch["action"], batch["next_obs"]
    policy = batch_actor(actor, cfg)  # (batch, obs_dim) -> (batch, act_dim)

    next_act = policy(learner.actor_target, next_obs)
    weight = None
    if cfg.held_aware:  # the action s' executes: mu'(s') only where s' refreshes it
        held = next_obs[:, INDEX["held"], None]  # (batch, 1), scale 1
        next_act = jnp.where(batch["refresh"][:, 1:] > 0.0, next_act, held)
        weight = batch["refresh"][:, 0]  # (batch,) the actor learns where its output acts
    next_q = critic.apply(learner.critic_target, next_obs, next_act)
    y = batch["reward"] + cfg.gamma * (1.0 - batch["terminated"]) * next_q  # (batch,)

    def critic_loss(params: Params) -> tuple[jax.Array, jax.Array]:
        q = critic.apply(params, obs, act)  # (batch,)
        return jnp.sum(jnp.mean(critic_error(q, y, cfg), axis=-1)), q

    def actor_loss(params: Params) -> jax.Array:
        q = critic.apply(learner.critic, obs, policy(params, obs))  # (batch,)
        if weight is None:
            return -jnp.mean(q)
        return -jnp.sum(weight * q) / jnp.maximum(jnp.sum(weight), 1.0)

    (c_loss, q), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(learner.critic)
    a_loss, a_grads = jax.value_and_grad(actor_loss)(learner.actor)
    new = apply_gradients(learner, c_grads, a_grads, hyper, cfg.tau)
    return new, {"critic_loss": c_loss, "actor_loss": a_loss, "mean_q": jnp.mean(q)}


def apply_gradients(
    learner: Learner, c_grads: Params, a_grads: Params, hyper: Hyper, tau: float
) -> Learner:
    """Both networks' ``optimizer_step`` (critic first) and the update count advanced."""
    critic_p, critic_opt, critic_t = optimizer_step(
        learner.critic, c_grads, learner.critic_opt, hyper.critic_lr, learner.critic_target, tau
    )
    actor_p, actor_opt, actor_t = optimizer_step(
        learner.actor, a_grads, learner.actor_opt, hyper.actor_lr, learner.actor_target, tau
    )
    return Learner(actor_p, critic_p, actor_t, critic_t, actor_opt, critic_opt, learner.step + 1)


def explore(
    key: jax.Array, action: jax.Array, sigma: jax.Array | float, noise_clip: float = 2.0
) -> jax.Array:
    """Action plus N(0, sigma) noise truncated at +-noise_clip*sigma, clipped to [-1, 1].

    ``action`` is ``(..., act_dim)`` in tanh units; ``sigma`` a () scalar (traced per model).
    """
    z = jax.random.truncated_normal(key, -noise_clip, noise_clip, action.shape, action.dtype)
    return jnp.clip(action + sigma * z, -1.0, 1.0)
