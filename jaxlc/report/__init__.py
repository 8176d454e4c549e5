"""What a run's evaluation looks like to a reader: ``report.md`` (``report``; its prose
``report_text``, its held-out sections ``report_heldout``, its section over seeds and
``compare.md`` ``report_seeds``) and the figures (``plots``, ``plots_scenes``).

Presentation only: every number comes from the evaluation's records
(``jaxlc.evaluation.results``, read by ``jaxlc.evaluation.numbers``); nothing here decides
or computes a result. Imports: ``jaxlc.evaluation`` and the layers below it; never the
top-level commands (``tests/test_layout.py`` checks it).
"""
