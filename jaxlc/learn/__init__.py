"""The learning layer: DDPG (or TD3) over a grid of models, vmapped and sharded, in one
``lax.scan``.

In: a ``Config`` (``jaxlc.config``) and the simulator (``jaxlc.sim``).
Out: the grid's init and jitted chunk functions (``train.make_grid_fns``), the training state
and per-episode logs they return, the actor and critic networks that checkpoints hold.

Modules: ``ddpg`` (the update), ``td3`` (TD3's update), ``learners`` (the learners by name,
``ddpg.learner``), ``networks``, ``replay``, ``train``, ``tree`` (one pytree select, here as
the lowest layer that uses it).

Imports: ``jaxlc.config`` and ``jaxlc.sim``; never ``study``, ``evaluation`` or the top-level
commands (``tests/test_layout.py`` checks it).
"""
