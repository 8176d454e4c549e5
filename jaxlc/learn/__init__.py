"""The learning layer: DDPG over a grid of models, vmapped and sharded, in one ``lax.scan``.

In: a ``Config`` (``jaxlc.config``) and the simulator (``jaxlc.sim``).
Out: the grid's init and jitted chunk functions (``train.make_grid_fns``), the training state
and per-episode logs they return, the actor and critic networks that checkpoints hold.

Modules: ``ddpg`` (the update), ``networks``, ``replay``, ``train``, ``tree`` (one pytree
select, here as the lowest layer that uses it).

Imports: ``jaxlc.config`` and ``jaxlc.sim``; never ``study``, ``evaluation`` or the top-level
commands (``tests/test_layout.py`` checks it).
"""
