"""The evaluation layer: trained policies on fixed cases, and what the results mean.

In: checkpoints and the run directory (``jaxlc.study``), the actor network (``jaxlc.learn``),
the simulator and its reason codes (``jaxlc.sim``), the ``Config`` (``jaxlc.config``).
Out: the evaluation protocol of a run (``protocol``), the fixed cases and every policy run on
them (``cases``) by the rollout engine (``engine``: a case's start and its manoeuvre on one
scheduler), the measures of a lane change, each declared once (``measures``), every key
stream (``keys``), the drawn cases' frames (``trace``), the typed results
(``results``) and the one module that writes and reads their files (``numbers``), statistics
over seeds (``stats``), the safety and comfort measures of a lane change (``safety``), the
held-out evaluation's bounds (``heldout``), learning speed from the training curves
(``convergence``). ``report.md`` and the figures draw these records: ``jaxlc.report``.

Imports: ``jaxlc.config``, ``jaxlc.sim``, ``jaxlc.learn`` and ``jaxlc.study``; never
``jaxlc.report`` or the top-level commands (``tests/test_layout.py`` checks it).
"""
