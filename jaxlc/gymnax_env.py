"""The lane-change task as a gymnax environment: one ``step`` is one RL decision.

    import jaxlc
    env, params = jaxlc.make_gymnax()           # pip install -e ".[gymnax]"
    obs, state = env.reset(key, params)
    obs, state, reward, done, info = env.step(key, state, action, params)

An episode is one lane change. The traffic before a manoeuvre, and episodes that end without
one (no acceptable gap, or a collision before the gap was accepted), run inside ``reset`` and
inside the step that ends a manoeuvre (``jaxlc.sim.decision``, shared with the gymnasium
wrapper), so a learner only ever sees decisions. Auto-reset continues the same road with the
next ego, as the simulator does: on ``done`` the returned ``obs`` and ``state`` are the next
manoeuvre's first, and the step's own last observation is ``info["final_observation"]``.

``step`` returns the five values that gymnax-based learners (Rejax, PureJaxRL) unpack;
``done = terminated | truncated``, and ``info`` tells them apart: ``terminated`` (success,
out of bounds, collision), ``truncated`` (the 10 s timeout, to bootstrap from; terminal
instead with ``env.terminal_timeout``), ``reason`` (a code of ``jaxlc.sim.reward.REASONS``),
``discount`` (0 only when terminated) and the reward terms. ``params.max_steps_in_episode`` is
the manoeuvre's decision limit (``manoeuvre_time_limit / dt``, 100): the simulator's own
timeout ends an episode there, and learners read it for their evaluation loops.

Given the same keys and actions it reproduces the gymnasium wrapper step for step
(``tests/test_gymnax.py``): the key a ``step`` receives drives ``decision.step_core``.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
from flax import struct
from gymnax.environments import environment, spaces
from jax import Array

from jaxlc.config import Config, EnvConfig
from jaxlc.sim import observation as obs_layout
from jaxlc.sim.decision import DEFAULT_MAX_SKIP_STEPS, reset_core, step_core
from jaxlc.sim.env import ACT_DIM, EnvParams, EnvState, make
from jaxlc.sim.observation import OBS_DIM


@struct.dataclass
class LaneChangeParams(environment.EnvParams):
    """gymnax params: the simulator's ``EnvParams`` and the decision loop's limits."""

    max_steps_in_episode: int = 100  # decisions in one manoeuvre (set by ``make_gymnax``)
    # Static: compiled in as constants, as the trainer and the gymnasium wrapper do. Traced,
    # XLA may fuse y - 1.5 W into one rounding, so the offset at the start of a manoeuvre is
    # no longer exactly +-W and a zero action can end it out of bounds at once.
    sim: EnvParams = struct.field(pytree_node=False, default_factory=EnvParams)
    # Env-steps the traffic between two decisions may run (``decision.fast_forward``).
    max_skip_steps: int = struct.field(pytree_node=False, default=DEFAULT_MAX_SKIP_STEPS)


@struct.dataclass
class LaneChangeState(environment.EnvState):
    """``time``: decisions so far in this manoeuvre; ``sim``: the whole highway."""

    sim: EnvState


class LaneChangeGymnax(environment.Environment):
    """The lane-change task for gymnax-based learners; pure, jittable, vmaps over envs."""

    @property
    def default_params(self) -> LaneChangeParams:
        return params_for(EnvParams())  # the paper's: EnvParams' defaults are the config's

    def reset(
        self, key: Array, params: LaneChangeParams | None = None
    ) -> tuple[Array, LaneChangeState]:
        """A fresh road, warmed up, then run to the first decision."""
        params = self.default_params if params is None else params
        _, sim, out = reset_core(key, params.sim, params.max_skip_steps)
        return out["obs"], LaneChangeState(time=jnp.int32(0), sim=sim)

    def step(
        self,
        key: Array,
        state: LaneChangeState,
        action: Array,
        params: LaneChangeParams | None = None,
    ) -> tuple[Array, LaneChangeState, Array, Array, dict[str, Any]]:
        """One decision; auto-resets to the next manoeuvre on the same road."""
        params = self.default_params if params is None else params
        _, _, nxt, out = step_core(key, state.sim, action, params.sim, params.max_skip_steps)
        terminated, truncated = out["terminated"], out["truncated"]
        done = terminated | truncated
        info = {
            "terminated": terminated,
            "truncated": truncated,
            "reason": out["reason_code"],
            "discount": 1.0 - terminated.astype(jnp.float32),
            "final_observation": out["obs"],
            "r_s": out["r_s"],
            "r_e": out["r_e"],
            "r_d": out["r_d"],
        }
        state = LaneChangeState(time=jnp.where(done, 0, state.time + 1), sim=nxt)
        return out["next_obs"], state, out["reward"], done, info

    # gymnax's hooks, for tools that call them directly: this env's reset and step already
    # are the environment-specific ones (the next manoeuvre follows on the same road).
    def reset_env(self, key: Array, params: LaneChangeParams) -> tuple[Array, LaneChangeState]:
        return self.reset(key, params)

    def step_env(
        self, key: Array, state: LaneChangeState, action: Array, params: LaneChangeParams
    ) -> tuple[Array, LaneChangeState, Array, Array, dict[str, Any]]:
        return self.step(key, state, action, params)

    def is_terminal(self, state: LaneChangeState, params: LaneChangeParams) -> Array:
        return jnp.bool_(False)  # every state a learner holds is one to act in

    @property
    def name(self) -> str:
        return "LaneChange-v0"

    @property
    def num_actions(self) -> int:
        return ACT_DIM

    def action_space(self, params: LaneChangeParams | None = None) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (ACT_DIM,), jnp.float32)

    def observation_space(self, params: LaneChangeParams | None = None) -> spaces.Box:
        """The bounds of ``jaxlc.sim.observation.bounds``."""
        params = self.default_params if params is None else params
        low, high = obs_layout.bounds(params.sim)
        return spaces.Box(jnp.asarray(low), jnp.asarray(high), (OBS_DIM,), jnp.float32)


def params_for(sim: EnvParams, max_skip_steps: int = DEFAULT_MAX_SKIP_STEPS) -> LaneChangeParams:
    """gymnax params around simulator params (the decision limit derived from them)."""
    limit = int(round(float(sim.manoeuvre_time_limit) / float(sim.dt)))
    return LaneChangeParams(max_steps_in_episode=limit, sim=sim, max_skip_steps=max_skip_steps)


def make_gymnax(
    config: Config | EnvConfig | None = None, k: int = 1
) -> tuple[LaneChangeGymnax, LaneChangeParams]:
    """``env, params = jaxlc.make_gymnax()``: the paper's defaults, or those of ``config``."""
    return LaneChangeGymnax(), params_for(make(config, k)[1])
