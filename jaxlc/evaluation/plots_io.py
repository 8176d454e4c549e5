"""What every figure module shares: matplotlib on its file backend (Agg: files only, no
display on training machines), a run's evaluation files, a figure saved."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # before pyplot is imported anywhere

import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.animation import PillowWriter  # noqa: E402, F401  (the figures' names for them)
from matplotlib.patches import Rectangle  # noqa: E402, F401

from jaxlc.evaluation.numbers import read  # noqa: E402
from jaxlc.evaluation.results import EvalResult  # noqa: E402
from jaxlc.study.rundir import RunDir  # noqa: E402

SCENE_BEHIND, SCENE_AHEAD = 90.0, 30.0  # m of road shown behind and ahead of the ego
npz = RunDir.load_npz


def eval_files(run_dir: Path) -> tuple[EvalResult, dict, dict] | None:
    """``(eval.json, traces.npz, cases.npz)`` of an evaluated run; None when one is missing."""
    path = RunDir(run_dir).eval_json
    traces, cases = npz(RunDir(run_dir).traces), npz(RunDir(run_dir).cases)
    if not path.is_file() or traces is None or cases is None:
        return None
    return read(path, EvalResult), traces, cases


def save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
