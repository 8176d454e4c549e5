"""Readers of committed evidence shared by the table modules: a study's ``eval/`` JSON, a
CSV's rows, a ``heldout.csv`` column per cell, the duration rule a held-out file was
evaluated under."""

from __future__ import annotations

import csv
import functools
from pathlib import Path
from typing import Any

import numpy as np

from jaxlc.evaluation.convergence import Convergence
from jaxlc.evaluation.numbers import read, read_csv
from jaxlc.evaluation.results import Heldout

ROOT = Path(__file__).resolve().parents[2]
BENCHMARKS = ROOT / "benchmarks"


@functools.cache
def load(study: Path, name: str) -> Any:
    """``study/eval/name`` (heldout.json, convergence.json) read once as its record."""
    return read(study / "eval" / name, Heldout if name == "heldout.json" else Convergence)


@functools.cache
def csv_rows(path: Path, of: type | None = None) -> tuple[Any, ...]:
    """A committed CSV's rows, read once: records of type ``of``, else text by column."""
    if of is not None:
        return tuple(read_csv(path, of))
    with path.open() as f:
        return tuple(csv.DictReader(f))


def per_seed(rows: tuple[Any, ...], column: str) -> dict[str, np.ndarray]:
    """A column's values over each cell's seeds (records of a CSV), by the cell's label."""
    cells: dict[str, list[float]] = {}
    for r in rows:
        if r.cell is not None:
            cells.setdefault(r.label, []).append(r.get(column))
    return {label: np.asarray(v, float) for label, v in cells.items()}


def per_cell(rows: tuple[Any, ...], column: str) -> dict[str, float]:
    """A heldout.csv column's mean over each cell's seeds, by the cell's label."""
    return {label: float(np.mean(v)) for label, v in per_seed(rows, column).items()}


def duration_rule(doc: Heldout) -> str:
    """Which time the evaluation held to 5 s, read off the norms ``heldout.json`` lists."""
    if any(n.measure == "lcm_s" for n in doc.norms):
        return (
            "The 5 s norm times UN R79's manoeuvre, the body from first over the line to "
            "wholly across it."
        )
    return "The 5 s norm times the whole RL phase (the rule before 2026-11-26)."
