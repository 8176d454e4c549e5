"""The paper (Wang, Li, Chan, IEEE IV 2019) as a plug-in: what jaxlc knows of its study.

Out: its nine models' tags by hyperparameters, the model its claims single out, its figures'
groups and colours (``grid``); its claims, what its figures show, and the comparisons each is
decided on (``claims``). The simulator, the learners, the sweep and the statistics work for any
grid without it; the evaluation's claim tables, the report, the figures and
``benchmarks/publish.py`` read the paper from here alone.

Imports: nothing outside ``jaxlc.paper`` (``tests/test_layout.py`` checks it).
"""
