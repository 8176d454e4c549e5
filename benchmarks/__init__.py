"""jaxlc's maintained benchmark and study scripts, each a command run from the repository root
as ``python -m benchmarks.NAME`` (``--help`` says what it measures and writes).

The dated folders beside them are the evidence the published tables are written from
(``python -m benchmarks.publish``); ``tables/`` holds one writer module per subject.
"""
