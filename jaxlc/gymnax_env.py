"""The lane-change task as a gymnax environment: one ``step`` is one RL decision.

    import jaxlc
    env, params = jaxlc.make_gymnax()           # pip install -e ".[gymnax]"
    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

An episode is one lane change. The traffic before a manoeuvre, and episodes that end without
one (no acceptable gap, or a collision before the gap was accepted), run inside ``reset`` and
inside the step that ends a manoeuvre (``jaxlc.sim.decision``, shared with the gymnasium
wrapper), so a learner only ever sees decisions. Auto-reset continues the same road with the
next ego, as the simulator does: on ``terminated | truncated`` the returned ``obs`` and
``state`` are the next manoeuvre's first, and the step's own last observation is
``info["final_observation"]``.

The contract is gymnax 1.x's: ``step`` returns six values, and is built, as gymnax's own
``Environment.step`` is, from ``step_env`` (one decision, no reset: ``obs, state, reward,
terminated, info``) and ``is_truncated(state, params)``; ``info`` gets ``terminated``,
``truncated`` and ``final_observation``. So gymnax's wrappers (``LogWrapper``,
``FlattenObservationWrapper``, ...) work on it. ``terminated``: success, out of bounds,
collision (and the timeout with ``env.terminal_timeout``); ``truncated``: the simulator's 10 s
timeout, to bootstrap from. ``info`` also has ``reason`` (a code of ``jaxlc.sim.reward.REASONS``),
``discount`` (0 only when terminated), the reward terms and the env's own ``episode_return``
and ``episode_steps``. ``params.max_steps_in_episode`` is the manoeuvre's decision limit
(``reward.step_limit``, 100), derived from the simulator's params; learners read it
for their evaluation loops.

Learners written for gymnax 0.0.x's five values ``obs, state, reward, done, info`` (Rejax
0.1.3, PureJaxRL's single files) take the env through ``FiveValueAdapter``:

    env5 = FiveValueAdapter(env)                # done = terminated | truncated

Given the same keys and actions it reproduces the gymnasium wrapper step for step
(``tests/test_gymnax.py``): the key a ``step`` receives is split as ``decision.step_core``
splits it.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct
from gymnax.environments import environment, spaces
from gymnax.wrappers.purerl import GymnaxWrapper
from jax import Array

from jaxlc.config import Config, EnvConfig
from jaxlc.sim import observation as obs_layout
from jaxlc.sim.decision import DEFAULT_MAX_SKIP_STEPS, fast_forward, reset_core
from jaxlc.sim.env import EnvParams, EnvState, LaneChangeEnv, action_dim, make, observation
from jaxlc.sim.observation import OBS_DIM
from jaxlc.sim.reward import names as reward_names
from jaxlc.sim.reward import step_limit

_SIM = LaneChangeEnv()


@struct.dataclass
class LaneChangeParams(environment.EnvParams):
    """gymnax params: the simulator's ``EnvParams`` and the decision loop's limits."""

    # Decisions in one manoeuvre, derived from the simulator's timeout by ``params_for``;
    # learners bound their evaluation loops with it. The simulator's own timeout ends an
    # episode (``is_truncated``), so set ``env.manoeuvre_time_limit`` to change it.
    max_steps_in_episode: int = 100
    # Static: compiled in as constants, as the trainer and the gymnasium wrapper do.
    sim: EnvParams = struct.field(pytree_node=False, default_factory=EnvParams)
    # Env-steps the traffic between two decisions may run (``decision.fast_forward``).
    max_skip_steps: int = struct.field(pytree_node=False, default=DEFAULT_MAX_SKIP_STEPS)


@struct.dataclass
class LaneChangeState(environment.EnvState):
    """``time``: decisions so far in this manoeuvre; ``sim``: the whole highway;
    ``truncated``: the decision that produced this state hit the simulator's timeout."""

    sim: EnvState
    # What ``is_truncated`` reads. gymnax's default rule, ``time >= max_steps_in_episode``,
    # would also flag a success or a crash on the 100th decision, and a timeout that
    # ``env.terminal_timeout`` makes terminal; the simulator knows which end it was.
    truncated: Array


class LaneChangeGymnax(environment.Environment):
    """The lane-change task for gymnax-based learners; pure, jittable, vmaps over envs.

    ``params`` (``params_for(...)``) become the env's ``default_params``, which gymnax's
    parameterless ``num_actions`` reads: the joint ego's is 2."""

    def __init__(self, params: LaneChangeParams | None = None) -> None:
        super().__init__()
        self._params = params

    @property
    def default_params(self) -> LaneChangeParams:
        if self._params is not None:
            return self._params
        return params_for(EnvParams())  # the paper's: EnvParams' defaults are the config's

    def reset_env(self, key: Array, params: LaneChangeParams) -> tuple[Array, LaneChangeState]:
        """A fresh road, warmed up, then run to the first decision."""
        _, sim, out = reset_core(key, params.sim, params.max_skip_steps)
        return out["obs"], LaneChangeState(time=jnp.int32(0), sim=sim, truncated=jnp.bool_(False))

    def step_env(
        self, key: Array, state: LaneChangeState, action: Array, params: LaneChangeParams
    ) -> tuple[Array, LaneChangeState, Array, Array, dict[str, Any]]:
        """One decision, no reset: ``(obs, state, reward, terminated, info)``, gymnax's
        environment-specific step. The state is the one the decision produced; when its
        manoeuvre ended, the ego has left the road and only ``step`` moves on to the next."""
        obs, sim, reward, terminated, truncated, out = _SIM.step(key, state.sim, action, params.sim)
        info = {
            "reason": out["reason"],
            "discount": 1.0 - terminated.astype(jnp.float32),
            **{n: out[n] for n in reward_names(params.sim)},  # each reward term
            "episode_return": out["episode_return"],
            "episode_steps": out["episode_steps"],
        }
        state = LaneChangeState(time=state.time + 1, sim=sim, truncated=truncated)
        return obs, state, reward, terminated, info

    def is_truncated(self, state: LaneChangeState, params: LaneChangeParams) -> Array:
        """The simulator's timeout: ``params.max_steps_in_episode`` decisions (10 s) without
        another end, truncating unless ``env.terminal_timeout``."""
        return state.truncated

    @partial(jax.jit, static_argnames=("self",))
    def step(
        self,
        key: Array,
        state: LaneChangeState,
        action: Array,
        params: LaneChangeParams | None = None,
    ) -> tuple[Array, LaneChangeState, Array, Array, Array, dict[str, Any]]:
        """gymnax's ``Environment.step`` but for the reset: on an end, the same road runs on
        to the next ego's first decision (``reset_env`` would warm up a fresh road, and under
        ``vmap`` every env would pay for that on every step)."""
        params = self.default_params if params is None else params
        # decision.step_core's split (the step's key second): the gymnasium wrapper's numbers.
        key_reset, key_step = jax.random.split(key)
        obs_st, state_st, reward, terminated, info = self.step_env(key_step, state, action, params)
        truncated = self.is_truncated(state_st, params)
        done = jnp.logical_or(terminated, truncated)
        # A no-op while the manoeuvre goes on: the ego is still under RL control.
        _, sim, _, _ = fast_forward(key_reset, state_st.sim, params.sim, params.max_skip_steps)
        obs = jnp.where(done, observation(sim, params.sim), obs_st)
        state = LaneChangeState(
            time=jnp.where(done, 0, state_st.time), sim=sim, truncated=jnp.zeros_like(truncated)
        )
        info = {
            **info,
            "terminated": terminated,
            "truncated": truncated,
            "final_observation": obs_st,
        }
        return obs, state, reward, terminated, truncated, info

    def is_terminal(self, state: LaneChangeState, params: LaneChangeParams) -> Array:
        return jnp.bool_(False)  # every state ``step`` returns is one to act in

    @property
    def name(self) -> str:
        return "LaneChange-v0"

    @property
    def num_actions(self) -> int:
        return action_dim(self.default_params.sim)

    def action_space(self, params: LaneChangeParams | None = None) -> spaces.Box:
        params = self.default_params if params is None else params
        return spaces.Box(-1.0, 1.0, (action_dim(params.sim),), jnp.float32)

    def observation_space(self, params: LaneChangeParams | None = None) -> spaces.Box:
        """The bounds of ``jaxlc.sim.observation.bounds``."""
        params = self.default_params if params is None else params
        low, high = obs_layout.bounds(params.sim)
        return spaces.Box(jnp.asarray(low), jnp.asarray(high), (OBS_DIM,), jnp.float32)


def params_for(sim: EnvParams, max_skip_steps: int = DEFAULT_MAX_SKIP_STEPS) -> LaneChangeParams:
    """gymnax params around simulator params (the decision limit derived from them)."""
    limit = int(step_limit(sim))
    return LaneChangeParams(max_steps_in_episode=limit, sim=sim, max_skip_steps=max_skip_steps)


def make_gymnax(
    config: Config | EnvConfig | None = None, k: int = 1
) -> tuple[LaneChangeGymnax, LaneChangeParams]:
    """``env, params = jaxlc.make_gymnax()``: ``jaxlc.make``'s arguments; the gymnax env and its
    ``LaneChangeParams`` (the simulator's params, the decision limit)."""
    return LaneChangeGymnax(), params_for(make(config, k)[1])


class FiveValueAdapter(GymnaxWrapper):
    """gymnax 0.0.x's step for learners that unpack five values (Rejax 0.1.3, PureJaxRL):
    ``obs, state, reward, done, info`` with ``done = terminated | truncated``; ``info`` keeps
    both apart. Wraps any gymnax 1.x env (this one, or it inside gymnax's wrappers); every
    other attribute is the wrapped env's.

        env, params = jaxlc.make_gymnax()
        algo = rejax.get_algo("ppo").create(env=FiveValueAdapter(env), env_params=params)
    """

    def __getattr__(self, name: str) -> Any:
        # A copy is built without ``__init__`` (Rejax deep-copies its config, env included);
        # gymnax's own ``__getattr__`` would then look up ``_env`` through itself forever.
        if name == "_env":
            raise AttributeError(name)
        return getattr(self._env, name)

    # Not jitted itself: the wrapped env's step is (gymnax's are), and one more jit would
    # compile that step again for the same arguments.
    def step(
        self, key: Array, state: Any, action: Array, params: Any = None
    ) -> tuple[Array, Any, Array, Array, dict[str, Any]]:
        obs, state, reward, terminated, truncated, info = self._env.step(key, state, action, params)
        return obs, state, reward, jnp.logical_or(terminated, truncated), info
