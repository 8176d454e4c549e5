"""The evaluation's numbers as they are written, read and printed: ``Record``, what every
result (``jaxlc.evaluation.results``) is, its JSON and CSV files (``write``, ``read``,
``csv_text``, ``read_csv``), which numbers are defined, and a number in a verdict's words
(``fixed``; the report's other formats: ``jaxlc.report.report_text``).

A record's fields are its columns in the files' order; an ``own`` field holds the columns a
run adds (its reward terms, measures registered with a held-out summary) where it stands.
Every committed file keeps its bytes: NaN is JSON's null, and a field an older file lacks
reads as its default (None)."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, TypeVar

from jaxlc.study.checkpoint import write_text_atomic

R = TypeVar("R", bound="Record")
DASH = "–"  # an undefined number in a markdown table (report.md, convergence verdicts)


def defined(v: Any) -> bool:
    """``v`` is a number: neither None (JSON's null) nor NaN."""
    return v is not None and v == v


def own() -> Any:
    """A record's columns of its own run: their names and values, spliced in where it stands."""
    return field(default_factory=dict, metadata={"own": True})


def many(of: type) -> Any:
    """A list of records of type ``of``."""
    return field(default_factory=list, metadata={"of": of})


def one(of: type) -> Any:
    """A record of type ``of`` (None: none)."""
    return field(default=None, metadata={"of": of})


def optional(default: Any = None) -> Any:
    """A field that older files lack and a file leaves out while it is None."""
    return field(default=default, metadata={"optional": True})


@dataclass
class Record:
    """A result's row or document: ``as_dict`` in the files' order, ``from_dict`` of what a
    file holds. Read by name too (``row["success_rate"]``, ``get``), for the scripts that
    read a row's columns by their names."""

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.metadata.get("own"):
                out.update(v)
            elif not (f.metadata.get("optional") and v is None):
                out[f.name] = _plain(v)
        return out

    @classmethod
    def from_dict(cls: type[R], data: dict[str, Any]) -> R:
        rest, kw = dict(data), {}
        for f in fields(cls):
            if f.name in rest and not f.metadata.get("own"):
                v = rest.pop(f.name)
                of = f.metadata.get("of")
                if of is not None and v is not None:
                    v = [of.from_dict(x) for x in v] if isinstance(v, list) else of.from_dict(v)
                kw[f.name] = v
        kw.update({f.name: rest for f in fields(cls) if f.metadata.get("own")})
        return cls(**kw)

    def get(self, name: str, default: Any = None) -> Any:
        """A column by its name, a field's or one of the run's own; ``default`` if none."""
        return self.as_dict().get(name, default)

    def __getitem__(self, name: str) -> Any:
        d = self.as_dict()
        if name not in d:
            raise KeyError(name)
        return d[name]

    def __contains__(self, name: str) -> bool:
        return name in self.as_dict()

    def keys(self) -> Iterator[str]:
        return iter(self.as_dict())

    __iter__ = keys


def _plain(v: Any) -> Any:
    if isinstance(v, Record):
        return v.as_dict()
    return [_plain(x) for x in v] if isinstance(v, list) else v


def _safe(obj: Any) -> Any:
    """JSON has no NaN: an undefined mean (no successes) is null."""
    if isinstance(obj, dict):
        return {k: _safe(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_safe(v) for v in obj]
    return None if isinstance(obj, float) and not math.isfinite(obj) else obj


def write(path: Path, doc: Record | dict[str, Any]) -> Path:
    """``doc`` as JSON (indent 1, a final newline), atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    d = doc.as_dict() if isinstance(doc, Record) else doc
    return write_text_atomic(path, json.dumps(_safe(d), indent=1) + "\n")


def read(path: Path, of: type[R]) -> R:
    """The record of type ``of`` that ``path`` (a JSON file ``write`` wrote) holds."""
    return of.from_dict(json.loads(Path(path).read_text()))


def csv_text(rows: Sequence[Record | dict[str, Any]], columns: Sequence[str] = ()) -> str:
    """``rows`` as CSV: ``columns``, else the first row's; an undefined number empty."""
    dicts = [r.as_dict() if isinstance(r, Record) else r for r in rows]
    columns = columns or (list(dicts[0]) if dicts else [])
    buf = io.StringIO()
    w = csv.DictWriter(buf, columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in dicts:
        w.writerow({k: r[k] if defined(r.get(k)) else "" for k in columns})
    return buf.getvalue()


def write_csv(path: Path, rows: Sequence[Record], columns: Sequence[str] = ()) -> Path:
    return write_text_atomic(path, csv_text(rows, columns))


def read_csv(path: Path, of: type[R]) -> list[R]:
    """A CSV ``csv_text`` wrote, as records of type ``of``: each field's text parsed by its
    type (empty: None); a column of the run's own as a number."""
    kinds = {f.name: str(f.type) for f in fields(of)}
    with Path(path).open() as f:
        return [
            of.from_dict({k: _parse(v, kinds.get(k, "")) for k, v in r.items()})
            for r in csv.DictReader(f)
        ]


def _parse(text: str, kind: str) -> Any:
    if text == "" or kind.startswith("str"):
        return text or None
    if kind.startswith("int"):
        return int(text)
    if kind.startswith("bool"):
        return text == "True"
    try:
        return float(text)
    except ValueError:
        return text


def number(v: Any) -> float:
    """``float(v)``, NaN for None (JSON's null)."""
    return math.nan if v is None else float(v)


def fixed(v: Any, fmt: str = ".2f", missing: str = DASH) -> str:
    """``v`` formatted by ``fmt``; ``missing`` where it is undefined."""
    return format(v, fmt) if defined(v) else missing
