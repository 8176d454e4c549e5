"""jaxlc: a JAX-accelerated lane-change DDPG trainer and batched traffic simulator."""

from jaxlc.env import EnvParams, EnvState, LaneChangeEnv, make

__version__ = "0.1.0"

__all__ = ["EnvParams", "EnvState", "LaneChangeEnv", "__version__", "make"]
