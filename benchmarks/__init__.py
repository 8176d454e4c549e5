"""jaxlc's maintained benchmark and study scripts, each ``python -m benchmarks.NAME`` from the
repository root (README.md beside them says which, and what the dated folders hold). Here:
their one CSV writer, and ``RESULTS``, their default output folder (git ignores it).
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Sequence
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def write_csv(
    path: Path, rows: Iterable[dict], fields: Sequence[str] | None = None, append: bool = False
) -> None:
    """``rows`` at ``path`` under the header ``fields`` (default: the first row's keys; keys
    not in ``fields`` are left out). ``append`` adds to an existing table, writing the header
    only when the file is new. The folder is made if missing."""
    rows = list(rows)
    fields = list(rows[0]) if fields is None else list(fields)
    path.parent.mkdir(parents=True, exist_ok=True)
    new = not append or not path.exists()
    with path.open("a" if append else "w", newline="") as f:
        w = csv.DictWriter(f, fields, extrasaction="ignore", lineterminator="\n")
        if new:
            w.writeheader()
        w.writerows(rows)
