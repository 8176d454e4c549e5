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
from jaxlc.sim.leaders import vehicle_y
from jaxlc.sim.reward import REASONS
from jaxlc.sim.road import reference_y, road_curvature

ENV_ID = "jaxlc/LaneChange-v0"


# Everything the host reads after a call travels as ONE float32 vector: fetching ~18 separate
# scalars costs more than the simulator step itself. Integers here stay far below 2**24, so
# float32 holds them exactly.
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

    ``params`` is closed over rather than passed: converting its ~40 Python floats to device
    arrays on every call took as long as the step. ``keep_terminal`` also returns the state a
    step produced (only rendering needs it; the extra outputs cost ~15 % of a call).
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


def render_frame(
    state: EnvState,
    params: EnvParams,
    *,
    view_m: float = 120.0,
    px_per_m: float = 8.0,
) -> np.ndarray:
    """``(H, W, 3)`` uint8 picture of one env's state (host or device arrays), a window of
    ``view_m`` metres of road centred on the ego: lanes, traffic (blue), the ego (red, drawn
    at its heading), the target lane shaded, and a bar along the top that fills up with the
    manoeuvre time. A curved road is drawn bent (``_bend``): the scene is drawn in the road
    frame, then mapped onto the arc; the picture is taller by the window's sagitta at the
    params' sharpest curvature, so every frame of an env has one shape."""
    tr, eg = jax.device_get((state.traffic, state.ego))
    kappa = float(road_curvature(state, params))
    p = params
    lanes, w, length, width = (
        p.lanes,
        float(p.lane_width),
        float(p.vehicle_length),
        float(p.vehicle_width),
    )
    s = px_per_m
    bar, shoulder = 6, int(round(1.5 * s))
    road_px = int(round(lanes * w * s))
    h_px, w_px = bar + 2 * shoulder + road_px, int(round(view_m * s))
    img = np.empty((h_px, w_px, 3), np.uint8)
    img[:] = (96, 140, 80)  # verge
    x0 = float(eg.x) - 0.5 * length - 0.5 * view_m  # world x of the left edge

    def col(x: float) -> int:
        return int(round((x - x0) * s))

    def row(y: float) -> int:  # lane 0 at the bottom, y upwards
        return int(round(bar + shoulder + (lanes * w - y) * s))

    def fill(x_lo: float, x_hi: float, y_lo: float, y_hi: float, rgb: tuple[int, ...]) -> None:
        c0, c1 = max(col(x_lo), 0), min(col(x_hi), w_px)
        r0, r1 = max(row(y_hi), 0), min(row(y_lo), h_px)
        if c0 < c1 and r0 < r1:
            img[r0:r1, c0:c1] = rgb

    fill(x0, x0 + view_m, 0.0, lanes * w, (70, 70, 74))
    target = int(eg.target)
    if target != lanes // 2:
        fill(x0, x0 + view_m, target * w, (target + 1) * w, (92, 92, 98))
    # Markings: solid road edges, 3 m dashes every 12 m between lanes, fixed to the road.
    line = max(1, int(round(0.15 * s)))
    for y in (0.0, lanes * w):
        r = row(y)
        img[max(r - line, 0) : r + line, :] = (235, 235, 235)
    for lane in range(1, lanes):
        r = row(lane * w)
        for start in np.arange(np.floor(x0 / 12.0) * 12.0, x0 + view_m, 12.0):
            c0, c1 = max(col(start), 0), min(col(start + 3.0), w_px)
            if c0 < c1:
                img[max(r - line // 2 - 1, 0) : r + line // 2 + 1, c0:c1] = (235, 235, 235)
    # Traffic: axis-aligned boxes, front bumper at x.
    active, xs = np.asarray(tr.active), np.asarray(tr.x)
    if tr.lane is None:  # rows are lanes
        ys = (np.arange(lanes)[:, None] + 0.5) * w + np.zeros_like(xs)
    else:  # with env.mobil: every body where it is, between two lanes while it changes
        ys = np.asarray(vehicle_y(tr, p))
    for x, yc in zip(xs[active], ys[active], strict=True):
        fill(x - length, x, yc - 0.5 * width, yc + 0.5 * width, (60, 120, 220))
    _draw_ego(img, eg, length, width, x0, bar + shoulder + lanes * w * s, s)
    ends = (p.curvature_min, p.curvature_max) if p.curvature_drawn else (p.curvature,)
    k_max = max(abs(float(k)) for k in ends)
    if k_max > 0.0:
        extra = int(np.ceil(view_m**2 * k_max / 8.0 * s))  # sagitta of the window, px
        ref_row = bar + shoulder + (lanes * w - float(reference_y(p))) * s
        img = _bend(img, kappa, bar, extra, ref_row, s)
    # Manoeuvre-time bar.
    limit = max(1, round(float(p.manoeuvre_time_limit) / float(p.dt)))
    img[:bar] = (30, 30, 30)
    img[:bar, : int(w_px * min(int(eg.steps), limit) / limit)] = (240, 190, 40)
    return img


def _draw_ego(
    img: np.ndarray, eg, length: float, width: float, x0: float, y0_row: float, s: float
) -> None:
    """The ego's rotated box (red), rasterised over its bounding rectangle; world x ``x0`` is
    column 0 and y = 0 is pixel row ``y0_row`` (y upwards), ``s`` px per metre."""
    h_px, w_px = img.shape[:2]
    c, sn = np.cos(float(eg.psi)), np.sin(float(eg.psi))
    cx, cy = float(eg.x) - 0.5 * length * c, float(eg.y) - 0.5 * length * sn
    half = 0.5 * (length * abs(c) + width * abs(sn)), 0.5 * (length * abs(sn) + width * abs(c))
    c0 = max(int(round((cx - half[0] - x0) * s)), 0)
    c1 = min(int(round((cx + half[0] - x0) * s)) + 1, w_px)
    r0 = max(int(round(y0_row - (cy + half[1]) * s)), 0)
    r1 = min(int(round(y0_row - (cy - half[1]) * s)) + 1, h_px)
    if c0 < c1 and r0 < r1:
        xx = x0 + (np.arange(c0, c1) + 0.5) / s - cx
        yy = (y0_row - (np.arange(r0, r1) + 0.5)) / s - cy
        along = xx[None, :] * c + yy[:, None] * sn
        across = -xx[None, :] * sn + yy[:, None] * c
        inside = (np.abs(along) <= 0.5 * length) & (np.abs(across) <= 0.5 * width)
        img[r0:r1, c0:c1][inside] = (220, 40, 40)


def _bend(
    img: np.ndarray, kappa: float, top: int, extra: int, ref_row: float, px_per_m: float
) -> np.ndarray:
    """The road-frame picture ``img`` (columns: s, rows below ``top``: d, the reference line
    at row ``ref_row``) mapped onto a road of curvature ``kappa``, ``extra`` rows taller above
    and below; its centre column stays where it is. Each pixel of the bent picture is the
    world point (X along the tangent at the window's centre, Y to the left) whose Frenet
    coordinates are, with R = 1/kappa and the bend's centre at (0, R),
    s = R*atan2(X/R, (R - Y)/R) and d = R - sign(R)*hypot(X, Y - R); it takes the colour of
    the nearest pixel of ``img`` (the verge's outside it)."""
    h, w_px, _ = img.shape
    verge = np.array((96, 140, 80), np.uint8)  # render_frame's verge
    rows = np.arange(top, h + 2 * extra) + 0.5
    cols = np.arange(w_px) + 0.5
    X = (cols[None, :] - 0.5 * w_px) / px_per_m
    Y = (ref_row + extra - rows[:, None]) / px_per_m
    if kappa == 0.0:
        s_w, d = np.broadcast_to(X, (rows.size, w_px)), np.broadcast_to(Y, (rows.size, w_px))
    else:
        R = 1.0 / kappa
        s_w = R * np.arctan2(X / R, (R - Y) / R)
        d = R - np.sign(R) * np.hypot(X, Y - R)
    c = np.round(0.5 * w_px + s_w * px_per_m - 0.5).astype(int)
    r = np.round(ref_row - d * px_per_m - 0.5).astype(int)
    ok = (c >= 0) & (c < w_px) & (r >= top) & (r < h)
    out = np.empty((top + rows.size, w_px, 3), np.uint8)
    out[:top] = img[:top]
    out[top:] = verge
    out[top:][ok] = img[r[ok], c[ok]]
    return out


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
