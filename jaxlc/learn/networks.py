"""Actor and critic MLPs of the paper (Fig. 2): hidden widths from ``DDPGConfig.hidden``, ReLU.

Params are the plain pytrees that ``flax.linen`` returns from ``init``; nothing here holds state.
The final layer starts near zero (U(+-final_init), [S]) so that early actions and Q values are
small and tanh does not saturate.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxlc.config import DDPGConfig
from jaxlc.sim.observation import MIRROR_SIGNS
from jaxlc.sim.state import ACTION_MIRROR


def uniform_pm(scale: float) -> nn.initializers.Initializer:
    """Initialiser U(-scale, scale); flax's ``uniform`` draws from [0, scale) only."""

    def init(key: jax.Array, shape: Sequence[int], dtype: jnp.dtype = jnp.float32) -> jax.Array:
        return jax.random.uniform(key, shape, dtype, -scale, scale)

    return init


class _Trunk(nn.Module):
    """Hidden ReLU layers then a linear head of width ``out`` with the small final init.

    Its params are ``{"Dense_0": {"kernel", "bias"}, ..., "Dense_L": ...}`` under the name
    ``mlp``: plain nested dicts, so a grid of models stacks, vmaps and saves as one pytree.
    """

    hidden: Sequence[int]
    out: int
    final_init: float

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.hidden:  # static layer count: unrolled at trace time
            x = nn.relu(nn.Dense(width)(x))
        head = uniform_pm(self.final_init)
        return nn.Dense(self.out, kernel_init=head, bias_init=head)(x)


class Actor(nn.Module):
    """Policy mu(s): ``(..., obs_dim) -> (..., act_dim)`` in [-1, 1] (tanh units).

    With ``mirror`` (the observation's signs under the road's reflection y -> -y) the policy
    is odd under that reflection by construction: mu(s) = (f(s) - f(Ms)) / 2 with one trunk
    f, so a left lane change is exactly the mirror image of a right one (why:
    docs/decisions.md, "an actor odd under the road's reflection"). The params are the same
    pytree either way (``ddpg.symmetric_actor``). With a
    longitudinal action (``env.longitudinal = "policy"``) that entry is even instead:
    mu(Ms) = (-lateral, +longitudinal).
    """

    hidden: Sequence[int] = (300, 600)
    act_dim: int = 1
    final_init: float = 3e-3
    mirror: tuple[float, ...] | None = None

    def setup(self) -> None:
        self.mlp = _Trunk(self.hidden, self.act_dim, self.final_init)

    def __call__(self, obs: jax.Array) -> jax.Array:
        if self.mirror is None:
            return jnp.tanh(self.mlp(obs))
        signs = jnp.asarray(self.mirror, obs.dtype)  # (obs_dim,)
        # One trunk call on (2, ..., obs_dim): one product per layer over s and Ms together
        # (XLA's CPU kernels prefer one tall product to two half-height ones).
        both = jnp.tanh(self.mlp(jnp.stack([obs, obs * signs])))  # (2, ..., act_dim)
        # mu(s) = (f(s) + A f(Ms)) / 2, A the action's signs: the yaw acceleration odd, the
        # longitudinal acceleration even (mu(Ms) = A mu(s)); A's entries are +-1, so for the
        # yaw action alone this is (f(s) - f(Ms)) / 2 to the bit.
        return 0.5 * (both[0] + self._signs(obs) * both[1])

    def paired(self, obs: jax.Array) -> jax.Array:
        """mu of a paired batch ``(batch, obs_dim)`` = ``[s; Ms]`` (``replay.sample(pairs=True)``)
        from one trunk pass over its rows: f(Ms) is a row of the batch already, so the odd
        actor costs the plain actor's FLOPs. Equal to ``__call__`` on the same rows (the
        trunk's rounding may differ with the product's height); a plain actor is ``__call__``.
        """
        if self.mirror is None:
            return self(obs)
        f = jnp.tanh(self.mlp(obs))  # (batch, act_dim): f(s) then f(Ms)
        half = obs.shape[0] // 2
        a = self._signs(obs)
        mu = 0.5 * (f[:half] + a * f[half:])  # mu(s), (batch / 2, act_dim)
        return jnp.concatenate([mu, a * mu])  # mu(Ms) = A mu(s): exact, A's entries are +-1

    def _signs(self, obs: jax.Array) -> jax.Array:
        return jnp.asarray(ACTION_MIRROR[: self.act_dim], obs.dtype)  # (act_dim,)


class Critic(nn.Module):
    """Q(s, a): ``(..., obs_dim), (..., act_dim) -> (...,)``; the input is concat(s, a)."""

    hidden: Sequence[int] = (300, 600)
    final_init: float = 3e-3

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, action], axis=-1)
        return _Trunk(self.hidden, 1, self.final_init, name="mlp")(x)[..., 0]


def actor_out_dim(actor_params: Any) -> int:
    """The action length of an actor's params pytree (its last layer's width)."""
    layers = actor_params["params"]["mlp"]
    last = max(layers, key=lambda name: int(name.rsplit("_", 1)[1]))
    return int(layers[last]["kernel"].shape[-1])


def batch_actor(actor: Actor, cfg: DDPGConfig) -> Callable[[Any, jax.Array], jax.Array]:
    """``actor.apply`` as an update applies it to a replay batch: ``Actor.paired`` when the
    batches are reflection pairs (``ddpg.mirror_pairs``)."""
    if cfg.mirror and cfg.mirror_pairs:
        return functools.partial(actor.apply, method=Actor.paired)
    return actor.apply


def make_networks(cfg: DDPGConfig, act_dim: int = 1) -> tuple[Actor, Critic]:
    """The two modules for a config (modules are static descriptions, cheap to rebuild)."""
    hidden = tuple(cfg.hidden)
    mirror = MIRROR_SIGNS if cfg.symmetric_actor else None
    return (
        Actor(hidden=hidden, act_dim=act_dim, final_init=cfg.final_init, mirror=mirror),
        Critic(hidden=hidden, final_init=cfg.final_init),
    )
