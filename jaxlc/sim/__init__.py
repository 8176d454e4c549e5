"""The simulator layer: the lane-change task as pure JAX functions over pytrees.

In: ``EnvConfig`` (``jaxlc.config``) turned into ``EnvParams``; PRNG keys and actions.
Out: ``LaneChangeEnv`` (``reset`` / ``step``), its state and observation layout, the reward
and its reason codes, the one-decision-per-step core the gym and gymnax wrappers share, and
the scripted controller.

Modules: ``env`` (the highway step), ``params``, ``state``, ``road``, ``traffic``, ``ego``,
``motion``, ``collision``, ``observation``, ``reward``, ``idm``, ``gap``, ``kinematics``,
``decision``, ``controller``, ``render`` (pictures); with the traffic that cuts in and brakes,
``leaders``, ``mobil``, ``braking``.

Imports: ``jaxlc.config`` only; no other layer (``tests/test_layout.py`` checks it).
"""
