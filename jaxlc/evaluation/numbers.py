"""The evaluation's numbers as they are read and printed: which are defined, and how an
estimate, a share or an interval is written in the report's tables, the terminal's and the
CSV files."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from typing import Any

DASH = "–"  # an undefined number in a markdown table (report.md, convergence verdicts)
TERMINAL_DASH = "-"  # the same in a plain-text table for the terminal (ASCII)


def defined(v: Any) -> bool:
    """``v`` is a number: neither None (JSON's null) nor NaN."""
    return v is not None and v == v


def csv_text(rows: list[dict[str, Any]], fields: Sequence[str]) -> str:
    """``rows`` as CSV: columns ``fields``, an undefined number empty, lines ending in LF."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fields, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: r[k] if defined(r.get(k)) else "" for k in fields})
    return buf.getvalue()


def number(v: Any) -> float:
    """``float(v)``, NaN for None (JSON's null)."""
    return math.nan if v is None else float(v)


def fixed(v: Any, fmt: str = ".2f", missing: str = DASH) -> str:
    """``v`` formatted by ``fmt``; ``missing`` where it is undefined."""
    return format(v, fmt) if defined(v) else missing


def percent(v: Any, digits: int = 1, unit: str = "%", missing: str = DASH) -> str:
    """A share ``v`` in [0, 1] as a percentage with ``digits`` decimals and ``unit``."""
    return f"{100 * v:.{digits}f}{unit}" if defined(v) else missing


def interval(est: Any, lo: Any, hi: Any, fmt: str, scale: float = 1.0) -> str:
    """``"est [lo, hi]"`` each times ``scale`` by ``fmt``; the estimate alone without bounds."""
    if not defined(est):
        return DASH
    text = format(scale * est, fmt)
    if defined(lo):
        text += f" [{format(scale * lo, fmt)}, {format(scale * hi, fmt)}]"
    return text
