"""jaxlc: a JAX-accelerated lane-change DDPG trainer and batched traffic simulator."""

from typing import Any

from jaxlc.sim.env import EnvParams, EnvState, LaneChangeEnv, make

__version__ = "0.1.0"

__all__ = ["EnvParams", "EnvState", "LaneChangeEnv", "__version__", "make", "make_gymnax"]


def make_gymnax(config: Any = None, k: int = 1) -> tuple[Any, Any]:
    """``env, params``: the task as a gymnax environment, one step per RL decision
    (``jaxlc.gymnax_env``; needs ``pip install -e ".[gymnax]"``)."""
    from jaxlc.gymnax_env import make_gymnax as make_env

    return make_env(config, k)
