"""Shrink a committed study folder to what its published numbers and its README need.

    python benchmarks/scripts/compact_evidence.py benchmarks/study_NAME [...] [--keep-gif]

Per folder (a run directory as ``python -m jaxlc.evaluate`` left it, or one holding several):

- ``eval/heldout_cases.npz`` (per policy and held-out case) becomes ``eval/failed_cases.csv``
  (``failed_cases.py``: every failed lane change, where the ego ended) and is removed;
- ``eval/cases.npz`` (per policy and protocol case) is removed: ``eval.csv``/``eval.json``
  hold each policy's counts and means over the cases;
- ``metrics/episodes.npz`` keeps what ``jaxlc.evaluation.convergence`` reads (``ret``
  float32, ``steps`` and ``reason`` in the smallest integer type that holds them, ``episodes``)
  and drops the reward terms and ``at_step``; the convergence measures of every model are
  checked equal before and after;
- every ``*.json`` is written without indentation (``json.loads`` gives the same document);
- ``figures/learning.gif`` is removed unless ``--keep-gif``.

Checkpoints are never committed, so what is removed comes back only by training and
evaluating again: the commands in the folder's ``README.md``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # run as a script from anywhere, without installing jaxlc
    sys.path.insert(0, str(ROOT))

from jaxlc.evaluation import convergence  # noqa: E402

KEEP = ("ret", "steps", "reason", "episodes")


def _same(a: object, b: object) -> bool:
    """Equal documents, NaN equal to NaN."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def _smallest(a: np.ndarray) -> np.ndarray:
    """``a`` in the smallest integer type that holds it exactly (int8 or int16, else as is)."""
    for dtype in (np.int8, np.int16):
        if a.dtype.kind == "i" and np.array_equal(a.astype(dtype).astype(a.dtype), a):
            return a.astype(dtype)
    return a


def compact_episodes(path: Path) -> None:
    with np.load(path) as f:
        full = {k: f[k] for k in f.files}
    small = {k: _smallest(full[k]) if k in ("steps", "reason") else full[k] for k in KEEP}
    before, after = convergence.run_measures(full), convergence.run_measures(small)
    assert _same(before, after), path  # the measures the convergence files hold
    np.savez_compressed(path, **small)


def minify(path: Path) -> None:
    text = path.read_text()
    doc = json.loads(text)
    out = json.dumps(doc, separators=(",", ":"), ensure_ascii=False)
    assert _same(json.loads(out), doc), path
    if len(out) < len(text):
        path.write_text(out)


def compact(folder: Path, keep_gif: bool) -> None:
    failed = importlib.util.spec_from_file_location(
        "failed", Path(__file__).parent / "failed_cases.py"
    )
    failed_cases = importlib.util.module_from_spec(failed)
    failed.loader.exec_module(failed_cases)
    for npz in folder.rglob("heldout_cases.npz"):
        failed_cases.main([str(npz.parent)])
        npz.unlink()
    for npz in folder.rglob("cases.npz"):
        npz.unlink()
    for npz in folder.rglob("metrics/episodes.npz"):
        compact_episodes(npz)
    for path in folder.rglob("*.json"):
        minify(path)
    if not keep_gif:
        for gif in folder.rglob("learning.gif"):
            gif.unlink()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--keep-gif", action="store_true", help="keep figures/learning.gif")
    args = ap.parse_args(argv)
    for folder in args.folders:
        compact(folder, args.keep_gif)


if __name__ == "__main__":
    main()
