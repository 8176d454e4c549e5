"""The learners the grid trainer runs, by name: ``ddpg.learner`` in the config.

A learner is a module with one interface (Rejax's layout: one module per algorithm):

    Hyper                                      per-model traced values (learning rates, sigma)
    Learner                                    the pytree state (params, targets, Adam, count)
    init_learner(key, obs_dim, cfg, act_dim)   -> Learner
    update(learner, batch, hyper, cfg, key)    -> (Learner, {"critic_loss", "actor_loss",
                                                  "mean_q"}), every metric ()
    explore(key, action, sigma, noise_clip)    the behaviour action from the actor's

``batch`` is what ``jaxlc.learn.replay.sample`` returns; ``key`` is the update's own draw. To add
a learner, write its module with these names and add it to ``LEARNERS``: the config accepts
its name and ``jaxlc.learn.train`` runs it over the grid, vmapped, with nothing else edited.
"""

from __future__ import annotations

from types import ModuleType

from jaxlc.config import DDPGConfig
from jaxlc.learn import ddpg, td3

LEARNERS: dict[str, ModuleType] = {"ddpg": ddpg, "td3": td3}


def of(cfg: DDPGConfig) -> ModuleType:
    """The learner module that ``cfg.learner`` names."""
    return LEARNERS[cfg.learner]
