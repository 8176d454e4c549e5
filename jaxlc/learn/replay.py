"""Replay memory for a grid of models under ``jax.vmap``: one array shape, per-model capacity.

Every model's arrays have the grid's largest capacity ``cap_max`` (static); the capacity that a
model actually uses is a traced int32 scalar, so models with memories of 2000, 4000 and 8000
are one vmapped program (docs/usage.md, "The sweep"). Slots ``[capacity, cap_max)`` are
never written. A memory is a ring: ``ptr`` is the next slot to write, ``size`` the number of
filled slots.
"""

from __future__ import annotations

import flax.struct
import jax
import jax.numpy as jnp


@flax.struct.dataclass
class Replay:
    obs: jax.Array  # (cap_max, obs_dim)
    action: jax.Array  # (cap_max, act_dim)
    reward: jax.Array  # (cap_max,)
    next_obs: jax.Array  # (cap_max, obs_dim)
    terminated: jax.Array  # (cap_max,) float32 0/1, ready to multiply the bootstrap term
    capacity: jax.Array  # () int32, <= cap_max
    ptr: jax.Array  # () int32, next slot to write, in [0, capacity)
    size: jax.Array  # () int32, filled slots, in [0, capacity]
    # (cap_max, 2) float32 0/1: the action is refreshed at s, at s' (``ddpg.held_aware``);
    # None otherwise, so the paper's memory and its programs are unchanged
    refresh: jax.Array | None = None


def init(
    cap_max: int, obs_dim: int, act_dim: int, capacity: jax.Array | int, held: bool = False
) -> Replay:
    """An empty memory with arrays of ``cap_max`` rows that uses the first ``capacity``;
    ``held``: it also keeps where the action is refreshed (``Replay.refresh``)."""
    f32 = jnp.float32
    return Replay(
        obs=jnp.zeros((cap_max, obs_dim), f32),
        action=jnp.zeros((cap_max, act_dim), f32),
        reward=jnp.zeros((cap_max,), f32),
        next_obs=jnp.zeros((cap_max, obs_dim), f32),
        terminated=jnp.zeros((cap_max,), f32),
        capacity=jnp.asarray(capacity, jnp.int32),
        ptr=jnp.zeros((), jnp.int32),
        size=jnp.zeros((), jnp.int32),
        refresh=jnp.zeros((cap_max, 2), f32) if held else None,
    )


def add(
    replay: Replay,
    obs: jax.Array,
    action: jax.Array,
    reward: jax.Array,
    next_obs: jax.Array,
    terminated: jax.Array,
    valid: jax.Array,
    refresh: jax.Array | None = None,
) -> Replay:
    """Insert the rows with ``valid`` set, in row order, overwriting the oldest when full.

    Shapes: obs/next_obs ``(n, obs_dim)``, action ``(n, act_dim)``, reward/terminated/valid
    ``(n,)``, ``refresh`` ``(n, 2)`` where the memory keeps it. Requires ``n <= capacity``:
    with more valid rows than slots two rows would land on one slot and which one survives is
    unspecified.
    """
    cap_max = replay.obs.shape[0]
    take = valid.astype(jnp.int32)
    rank = jnp.cumsum(take) - take  # position among the valid rows: compacts the gaps
    # invalid rows go past the end, where mode="drop" discards them: no Python loop, no branch
    slot = jnp.where(valid, (replay.ptr + rank) % replay.capacity, cap_max)

    def put(buf: jax.Array, rows: jax.Array) -> jax.Array:
        return buf.at[slot].set(rows.astype(buf.dtype), mode="drop")

    n_valid = take.sum()
    return replay.replace(
        obs=put(replay.obs, obs),
        action=put(replay.action, action),
        reward=put(replay.reward, reward),
        next_obs=put(replay.next_obs, next_obs),
        terminated=put(replay.terminated, terminated),
        ptr=(replay.ptr + n_valid) % replay.capacity,
        size=jnp.minimum(replay.size + n_valid, replay.capacity),
        refresh=None if replay.refresh is None else put(replay.refresh, refresh),
    )


def sample(
    replay: Replay,
    key: jax.Array,
    batch_size: int,
    mirror: tuple[float, ...] | None = None,
    action_mirror: tuple[float, ...] | None = None,
    pairs: bool = False,
) -> dict[str, jax.Array]:
    """``batch_size`` transitions drawn uniformly, with replacement, from the filled slots.

    Returns obs/next_obs ``(batch, obs_dim)``, action ``(batch, act_dim)``, reward/terminated
    ``(batch,)``, and refresh ``(batch, 2)`` where the memory keeps it. An empty memory yields
    slot 0 (zeros); callers start updating once a batch is stored ([P]/[S]: docs/decisions.md).

    With ``mirror`` (per-entry signs of the reflection, ``jaxlc.sim.observation.MIRROR_SIGNS``)
    each drawn transition is reflected with probability 1/2: obs and next obs times the signs,
    action times ``action_mirror`` (default: negated, the yaw acceleration; a longitudinal
    entry keeps its sign, ``jaxlc.sim.state.ACTION_MIRROR``); reward and end unchanged. The
    draw of the slots is the same either way.

    With ``pairs`` (``ddpg.mirror_pairs``) ``batch_size // 2`` transitions are drawn and the
    batch is those rows, then each one reflected, in that order: ``[s; Ms]``, the layout
    ``Actor.paired`` reads so that the odd actor runs its trunk once per row.
    """
    if pairs and mirror is not None:
        half = sample(replay, key, batch_size // 2)
        flipped = _reflect(half, mirror, action_mirror, True)
        return {n: jnp.concatenate([v, flipped[n]]) for n, v in half.items()}
    idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(replay.size, 1))
    batch = {
        "obs": replay.obs[idx],
        "action": replay.action[idx],
        "reward": replay.reward[idx],
        "next_obs": replay.next_obs[idx],
        "terminated": replay.terminated[idx],
    }
    if replay.refresh is not None:
        batch["refresh"] = replay.refresh[idx]  # (batch, 2)
    if mirror is None:
        return batch
    flip = jax.random.bernoulli(jax.random.fold_in(key, 1), 0.5, (batch_size, 1))
    return _reflect(batch, mirror, action_mirror, flip)


def _reflect(
    batch: dict[str, jax.Array],
    mirror: tuple[float, ...],
    action_mirror: tuple[float, ...] | None,
    flip: jax.Array | bool,
) -> dict[str, jax.Array]:
    """The rows where ``flip`` (``(batch, 1)`` or one bool) reflected: obs and next obs times
    the observation's signs, the action times ``action_mirror`` (default: every entry
    negated); reward and end unchanged."""
    if action_mirror is None:
        action_mirror = (-1.0,) * batch["action"].shape[-1]
    signs = jnp.where(flip, jnp.asarray(mirror, jnp.float32), 1.0)  # (batch | 1, obs_dim)
    a_signs = jnp.where(flip, jnp.asarray(action_mirror, jnp.float32), 1.0)  # (batch | 1, act)
    return batch | {
        "obs": batch["obs"] * signs,
        "action": batch["action"] * a_signs,
        "next_obs": batch["next_obs"] * signs,
    }
