"""One RL decision per step: the functional env with the traffic between manoeuvres run inside.

The simulator (``jaxlc.sim.env``) advances the whole highway every dt while the ego goes through
WAIT, CRUISE and GAP before the RL phase; only RL-phase steps are decisions. ``fast_forward``
runs the simulator with no action, in one ``lax.while_loop``, through those phases and through
whole episodes that end before any RL step (no gap found, or a collision before the gap was
accepted), until the next gap is accepted or ``max_steps`` steps ran. ``reset_core`` and
``step_core`` build on it, so an episode is exactly one lane change and each step one decision.
The gymnasium wrapper (``jaxlc.gym``) is a thin front over these three pure functions; the
gymnax env (``jaxlc.gymnax_env``) uses ``reset_core`` and ``fast_forward``, and splits its
step's key as ``step_core`` does (its gymnax ``step_env`` is the simulator's step alone).

Randomness: ``reset_core`` and ``step_core`` split their key once per simulator step, always
in the same order, so a rollout can be replayed step for step with the functional API.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.sim.env import RL, EnvParams, EnvState, LaneChangeEnv, action_dim, observation
from jaxlc.sim.reward import NONE
from jaxlc.sim.reward import names as reward_names

# Env-steps the fast-forward may run before giving up: ~33 simulated minutes, far beyond the
# ~30 s one episode takes (an ego needs ~15-25 s to reach the command point, then at most 5 s
# of gap search), so only a config in which no gap is ever acceptable reaches it.
DEFAULT_MAX_SKIP_STEPS = 20_000
_ENV = LaneChangeEnv()


def fast_forward(
    key: Array, state: EnvState, params: EnvParams, max_steps: Array | int
) -> tuple[Array, EnvState, Array, Array]:
    """Step with no action until the ego is under RL control, at most ``max_steps`` steps.

    Returns ``(key, state, steps_run, episodes_ended)``; the last counts episodes that ended
    without an RL step (no gap, or a collision before the gap was accepted). A state already
    in the RL phase is returned as it is, key included.
    """

    no_action = jnp.zeros(action_dim(params), jnp.float32)

    def cond(carry: tuple[Array, EnvState, Array, Array]) -> Array:
        _, s, n, _ = carry
        return (s.ego.phase != RL) & (n < max_steps)

    def body(carry: tuple[Array, EnvState, Array, Array]) -> tuple[Array, EnvState, Array, Array]:
        key, s, n, ended = carry
        key, k = jax.random.split(key)
        _, s, _, _, _, info = _ENV.step(k, s, no_action, params)
        return key, s, n + 1, ended + (info["reason"] != NONE)

    zero = jnp.int32(0)
    return jax.lax.while_loop(cond, body, (key, state, zero, zero))


def reset_core(
    key: Array, params: EnvParams, max_steps: Array | int
) -> tuple[Array, EnvState, dict[str, Array]]:
    """A fresh road (``env.reset``), then ``fast_forward`` to the first RL decision.

    Returns ``(key, state, out)`` with ``out``: ``obs``, ``ready`` (the ego is under RL
    control; False only if ``max_steps`` ran out), ``skipped_steps``, ``skipped_episodes``,
    ``target_lane``.
    """
    key, k_reset = jax.random.split(key)
    _, state = _ENV.reset(k_reset, params)
    key, state, n, ended = fast_forward(key, state, params, max_steps)
    out = {
        "obs": observation(state, params),
        "ready": state.ego.phase == RL,
        "skipped_steps": n,
        "skipped_episodes": ended,
        "target_lane": state.ego.target,
    }
    return key, state, out


def step_core(
    key: Array, state: EnvState, action: Array, params: EnvParams, max_steps: Array | int
) -> tuple[Array, EnvState, EnvState, dict[str, Array]]:
    """One RL decision of an env whose ego is under RL control.

    One ``env.step``; if it ended the manoeuvre, ``fast_forward`` to the next one. Returns
    ``(key, state_after_step, next_state, out)``: ``state_after_step`` is the state the
    step produced (terminal when the manoeuvre ended), ``next_state`` the one to act in next
    (the same state when the manoeuvre goes on). ``out`` holds the step's ``obs``, ``reward``,
    ``terminated``, ``truncated``, each reward term by name, and ``next_obs``/``ready``/
    ``skipped_*``/``target_lane`` of ``next_state``.
    """
    key, k = jax.random.split(key)
    obs, after, reward, terminated, truncated, info = _ENV.step(k, state, action, params)
    key, nxt, n, ended = fast_forward(key, after, params, max_steps)
    out = {
        "obs": obs,
        "reward": reward,
        "terminated": terminated,
        "truncated": truncated,
        "rl_step": info["rl_step"],
        "reason_code": info["reason"],
        **{n: info[n] for n in reward_names(params)},  # each reward term
        "episode_return": info["episode_return"],
        "episode_steps": info["episode_steps"],
        "offset": info["offset"],
        "action": info["action"],
        "next_obs": observation(nxt, params),
        "ready": nxt.ego.phase == RL,
        "skipped_steps": n,
        "skipped_episodes": ended,
        "target_lane": nxt.ego.target,
    }
    return key, after, nxt, out
