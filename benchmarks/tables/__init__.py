"""The tables ``benchmarks/publish.py`` writes, one module per subject.

Each module names the committed folders it reads at its top and ends with ``BLOCKS``, its
writers by block name (``<!-- publish:NAME -->``); ``common`` holds the readers they share.
"""
