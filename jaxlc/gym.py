"""Gymnasium front end: one lane change per episode, one RL decision per step.

    import gymnasium as gym
    import jaxlc.gym  # registers "jaxlc/LaneChange-v0"

    env = gym.make("jaxlc/LaneChange-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    frame = env.render()                                   # (H, W, 3) uint8

    envs = gym.make_vec("jaxlc/LaneChange-v0", num_envs=64)  # LaneChangeVectorEnv, one jit call

Each ``step`` is one RL decision and an episode exactly one lane change: the traffic before a
manoeuvre runs inside (``jaxlc.sim.decision``, shared with the gymnax env). ``terminated`` /
``truncated`` mean what they mean in the functional env (success, out of bounds and collision
terminate; the 10 s timeout truncates, so a learner bootstraps from it).

Randomness: one JAX key per env. ``reset(seed=s)`` starts from ``PRNGKey(s)``; ``reset_core``
and ``step_core`` split it once per simulator step, always in the same order, so a wrapper
rollout can be replayed step for step with the functional API (tests/test_gym.py does so).
``reset()`` without a seed right after an episode ended continues the same traffic with the
next ego (its first observation was computed by the step that ended the episode); in the middle
of an episode it starts a fresh road (new warm-up) drawn from the key stream. A ``reset()``
with no seed before any seeded one draws the key from ``self.np_random``.

The observation space's bounds are ``jaxlc.sim.observation.bounds`` (why each holds is written
there): finite on straight and curved roads alike (the ego holds its lane until the RL phase).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any, NamedTuple

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from jax import Array

from jaxlc.config import Config, EnvConfig
from jaxlc.sim import observation as obs_layout
from jaxlc.sim import reward
from jaxlc.sim.decision import DEFAULT_MAX_SKIP_STEPS, reset_core, step_core
from jaxlc.sim.env import OBS_DIM, EnvParams, EnvState, action_dim, make
from jaxlc.sim.render import render_frame
from jaxlc.sim.reward import REASONS

ENV_ID = "jaxlc/LaneChange-v0"


# Everything the host reads after a call travels as ONE float32 vector (one device-to-host
# copy instead of one per scalar). Integers here stay far below 2**24, so float32 holds them
# exactly.
_STEP_HEAD = (
    ("obs", OBS_DIM),
    ("next_obs", OBS_DIM),
    ("reward", 1),
    ("terminated", 1),
    ("truncated", 1),
    ("rl_step", 1),
    ("reason_code", 1),
)
_STEP_TAIL = (
    ("episode_return", 1),
    ("episode_steps", 1),
    ("offset", 1),
    ("action", 1),  # action_dim entries (``_step_fields``)
    ("ready", 1),
    ("skipped_steps", 1),
    ("skipped_episodes", 1),
    ("target_lane", 1),
)


def _step_fields(params: EnvParams) -> tuple[tuple[str, int], ...]:
    """What a step returns: the head, each of ``params``' reward terms, the tail."""
    terms = ((n, 1) for n in reward.names(params))
    tail = ((n, action_dim(params) if n == "action" else size) for n, size in _STEP_TAIL)
    return (*_STEP_HEAD, *terms, *tail)


_RESET_FIELDS = (
    ("obs", OBS_DIM),
    ("ready", 1),
    ("skipped_steps", 1),
    ("skipped_episodes", 1),
    ("target_lane", 1),
)
_INT_FIELDS = ("reason_code", "episode_steps", "skipped_steps", "skipped_episodes", "target_lane")
_BOOL_FIELDS = ("terminated", "truncated", "rl_step", "ready")


def _pack(out: dict[str, Array], fields: tuple[tuple[str, int], ...]) -> Array:
    return jnp.concatenate([jnp.reshape(out[n], (size,)).astype(jnp.float32) for n, size in fields])


def _unpack(flat: np.ndarray, fields: tuple[tuple[str, int], ...]) -> dict[str, np.ndarray]:
    """Inverse of ``_pack`` along the last axis, on the host; size-1 fields lose that axis.
    Every field is a fresh contiguous array (callers may keep and modify what they get)."""
    out, i = {}, 0
    for name, size in fields:
        v = flat[..., i : i + size] if size > 1 else flat[..., i]
        if name in _BOOL_FIELDS:
            v = v != 0
        elif name in _INT_FIELDS:
            v = v.astype(np.int64)
        out[name] = np.array(v, order="C")
        i += size
    return out


class _Programs(NamedTuple):
    fields: tuple[tuple[str, int], ...]  # a step's packed outputs (``_step_fields``)
    info: tuple[str, ...]  # a step's info entries (``_step_info``)
    reset: Any  # key -> (key, state, packed)
    step: Any  # (key, state, action) -> (key, [terminal state,] next state, packed)
    vreset: Any  # batched reset
    vstep: Any  # batched step, no terminal state


@functools.lru_cache(maxsize=32)
def _programs(params: EnvParams, max_steps: int, keep_terminal: bool) -> _Programs:
    """Jitted reset/step for one ``params``, shared by every wrapper with those params.

    ``params`` is closed over rather than passed (converting its Python floats to device
    arrays on every call costs as much as the step). ``keep_terminal`` also returns the state
    a step produced, for rendering only (the extra outputs slow every call).
    """

    fields = _step_fields(params)

    def reset(key: Array) -> tuple[Array, EnvState, Array]:
        key, state, out = reset_core(key, params, max_steps)
        return key, state, _pack(out, _RESET_FIELDS)

    def step(key: Array, state: EnvState, action: Array) -> tuple[Any, ...]:
        key, after, nxt, out = step_core(key, state, action, params, max_steps)
        packed = _pack(out, fields)
        return (key, after, nxt, packed) if keep_terminal else (key, nxt, packed)

    def vstep(key: Array, state: EnvState, action: Array) -> tuple[Array, EnvState, Array]:
        key, _, nxt, out = step_core(key, state, action, params, max_steps)
        return key, nxt, _pack(out, fields)

    # Under vmap the while_loop runs until every env is ready again; envs already ready keep
    # their carry (key included), so each env's key stream is the one it has when stepped alone.
    return _Programs(
        fields=fields,
        info=_step_info(params),
        reset=jax.jit(reset),
        step=jax.jit(step),
        vreset=jax.jit(jax.vmap(reset)),
        vstep=jax.jit(jax.vmap(vstep)),
    )


def _configure(
    env: Any,
    config: Config | EnvConfig | None,
    k: int,
    params: EnvParams | None,
    render_mode: str | None,
    max_skip_steps: int,
) -> tuple[spaces.Box, spaces.Box]:
    """The constructor arguments both wrappers share: checks ``render_mode``, sets
    ``params``, ``render_mode`` and ``max_skip_steps`` on ``env``, and returns one env's
    observation and action spaces."""
    if render_mode is not None and render_mode not in env.metadata["render_modes"]:
        raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
    env.params = params if params is not None else make(config, k=k)[1]
    env.render_mode = render_mode
    env.max_skip_steps = int(max_skip_steps)
    low, high = obs_layout.bounds(env.params)
    obs_space = spaces.Box(low, high, (OBS_DIM,), np.float32)
    return obs_space, spaces.Box(-1.0, 1.0, (action_dim(env.params),), np.float32)


def _reason_names(codes: np.ndarray) -> np.ndarray:
    return np.asarray(REASONS)[codes]


def _step_info(params: EnvParams) -> tuple[str, ...]:
    """A step's info entries: each reward term of ``params``, then the manoeuvre's."""
    return (*reward.names(params), "episode_return", "episode_steps", "offset", "action")


_RESET_INFO = ("skipped_steps", "skipped_episodes", "target_lane")
_NEXT_INFO = ("ready", *_RESET_INFO)


# --- single env -----------------------------------------------------------------------------


class LaneChangeGymEnv(gymnasium.Env[np.ndarray, np.ndarray]):
    """One jaxlc highway as a ``gymnasium.Env``; an episode is one lane change.

    Args:
        config: a ``Config`` or ``EnvConfig`` (default: configs/default.toml), as ``jaxlc.make``.
        k: the action-update step (the action is held for ``k`` RL steps).
        params: ready-made ``EnvParams``; overrides ``config`` and ``k``.
        render_mode: ``None`` or ``"rgb_array"``.
        max_skip_steps: cap on the env-steps one fast-forward may run.

    ``step`` info: ``reason`` (name from ``jaxlc.sim.reward.REASONS``, "none" while the manoeuvre
    goes on), ``reason_code``, each reward term by name (``r_s``/``r_e``/``r_d``, eqs. (8)-(10),
    and any other of ``env.reward_terms``),
    ``episode_return``/``episode_steps`` of the manoeuvre so far, ``offset`` (m from the target
    lane's centre) and ``action`` (the executed, held action). ``reset`` info:
    ``skipped_steps``/``skipped_episodes`` run by the fast-forward and ``target_lane``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        config: Config | EnvConfig | None = None,
        k: int = 1,
        params: EnvParams | None = None,
        render_mode: str | None = None,
        max_skip_steps: int = DEFAULT_MAX_SKIP_STEPS,
    ) -> None:
        self.observation_space, self.action_space = _configure(
            self, config, k, params, render_mode, max_skip_steps
        )
        self._programs = _programs(self.params, self.max_skip_steps, render_mode is not None)
        self._key: Array | None = None
        self._state: EnvState | None = None  # the state acted in, or the terminal one
        self._next: tuple[EnvState, dict[str, np.ndarray]] | None = None  # prefetched episode
        self._done = True

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self._key = jax.random.PRNGKey(seed)
        elif self._key is None:
            self._key = jax.random.PRNGKey(int(self.np_random.integers(2**31)))
        if seed is None and self._done and self._next is not None:
            state, out = self._next  # the step that ended the episode already found this one
        else:
            self._key, state, packed = self._programs.reset(self._key)
            out = _unpack(np.asarray(packed), _RESET_FIELDS)
        if not out["ready"]:
            raise RuntimeError(
                f"no lane change started within max_skip_steps={self.max_skip_steps} env-steps; "
                "the traffic config leaves no acceptable gap"
            )
        self._state, self._next, self._done = state, None, False
        info = {name: int(out[name]) for name in _RESET_INFO}
        return out["obs"], info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise gymnasium.error.ResetNeeded(
                "call reset() before step() and after an episode ends"
            )
        a = np.asarray(action, np.float32).reshape(action_dim(self.params))
        self._key, *states, packed = self._programs.step(self._key, self._state, a)
        out = _unpack(np.asarray(packed), self._programs.fields)
        terminated, truncated = bool(out["terminated"]), bool(out["truncated"])
        nxt = states[-1]
        if terminated or truncated:
            # Keep the terminal state for render(); reset() resumes from the prefetched one.
            self._done = True
            self._next = (nxt, {"obs": out["next_obs"], **{n: out[n] for n in _NEXT_INFO}})
            self._state = states[0] if len(states) == 2 else None
        else:
            self._state = nxt
        code = int(out["reason_code"])
        info: dict[str, Any] = {"reason": REASONS[code], "reason_code": code}
        for name in self._programs.info:
            info[name] = out[name].item() if out[name].size == 1 else out[name]
        return out["obs"], float(out["reward"]), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._state is None:
            raise gymnasium.error.ResetNeeded("call reset() before render()")
        return render_frame(self._state, self.params)


# --- vector env -----------------------------------------------------------------------------


class LaneChangeVectorEnv(VectorEnv):
    """``num_envs`` highways stepped by one jitted, vmapped call per ``step``.

    Autoreset is ``AutoresetMode.SAME_STEP``: when a sub-env's manoeuvre ends, the returned
    observation is already the first one of its next lane change, and the terminal one is in
    ``infos["final_obs"]`` (a dense ``(num_envs, OBS_DIM)`` float32 array, valid where
    ``infos["_final_obs"]``; gymnasium's SyncVectorEnv uses an object array instead). The other
    ``infos`` entries are ``(num_envs,)`` arrays of the single env's step info for the step just
    taken, plus ``skipped_steps``/``skipped_episodes``/``target_lane`` of the episode now
    running. Sub-env ``i`` of ``reset(seed=s)`` is seeded ``s + i``, as SyncVectorEnv seeds its
    envs, so it replays a ``LaneChangeGymEnv`` reset with seed ``s + i``.
    """

    metadata = {
        "render_modes": ["rgb_array"],
        "render_fps": 10,
        "autoreset_mode": AutoresetMode.SAME_STEP,
    }

    def __init__(
        self,
        num_envs: int,
        config: Config | EnvConfig | None = None,
        k: int = 1,
        params: EnvParams | None = None,
        render_mode: str | None = None,
        max_skip_steps: int = DEFAULT_MAX_SKIP_STEPS,
    ) -> None:
        self.single_observation_space, self.single_action_space = _configure(
            self, config, k, params, render_mode, max_skip_steps
        )
        self.num_envs = int(num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._programs = _programs(self.params, self.max_skip_steps, False)
        self._keys: Array | None = None
        self._state: EnvState | None = None

    def reset(
        self,
        *,
        seed: int | Sequence[int] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed if isinstance(seed, int) else None)
        if seed is None and self._keys is None:
            seed = int(self.np_random.integers(2**31))
        if seed is not None:
            seeds = [seed + i for i in range(self.num_envs)] if isinstance(seed, int) else seed
            if len(seeds) != self.num_envs:
                raise ValueError(f"expected {self.num_envs} seeds, got {len(seeds)}")
            self._keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
        self._keys, self._state, packed = self._programs.vreset(self._keys)
        out = _unpack(np.asarray(packed), _RESET_FIELDS)
        self._check_ready(out["ready"])
        return out["obs"], {n: out[n] for n in _RESET_INFO}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if self._state is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        a = np.asarray(actions, np.float32).reshape(self.num_envs, action_dim(self.params))
        self._keys, self._state, packed = self._programs.vstep(self._keys, self._state, a)
        out = _unpack(np.asarray(packed), self._programs.fields)
        self._check_ready(out["ready"])
        codes = out["reason_code"]
        infos: dict[str, Any] = {"reason": _reason_names(codes), "reason_code": codes}
        for name in (*self._programs.info, *_RESET_INFO):
            infos[name] = out[name]
        infos["final_obs"] = out["obs"]
        infos["_final_obs"] = out["terminated"] | out["truncated"]
        return out["next_obs"], out["reward"], out["terminated"], out["truncated"], infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        if self.render_mode != "rgb_array":
            return None
        if self._state is None:
            raise gymnasium.error.ResetNeeded("call reset() before render()")
        host = jax.device_get(self._state)
        return tuple(
            render_frame(jax.tree.map(lambda a, i=i: a[i], host), self.params)
            for i in range(self.num_envs)
        )

    def _check_ready(self, ready: np.ndarray) -> None:
        if not np.all(ready):
            raise RuntimeError(
                f"envs {np.nonzero(~np.asarray(ready))[0].tolist()} started no lane change "
                f"within max_skip_steps={self.max_skip_steps} env-steps; the traffic config "
                "leaves no acceptable gap"
            )


if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=ENV_ID,
        entry_point="jaxlc.gym:LaneChangeGymEnv",
        vector_entry_point="jaxlc.gym:LaneChangeVectorEnv",
    )
