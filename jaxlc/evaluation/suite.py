"""The held-out suite: a run's policies driven in each of a list of named settings of the
traffic and the road (a suite file, ``configs/suite.toml``: ``base`` overrides, then each
setting's own, applied to the run's config), each setting's held-out lane changes as
``protocol.evaluate_heldout`` runs them (``eval/heldout_suite_NAME/``), gathered into
``eval/suite/suite.csv`` (a row per model and setting: the commands, those declined outside
the operating range, the lane changes, their ends and the success rate with its 95%
Clopper-Pearson interval) and ``suite.png`` (success by setting).

    python -m jaxlc.evaluate RUN --suite            # eval.suite, else configs/suite.toml
    python -m jaxlc.evaluate RUN --suite FILE.toml
"""

from __future__ import annotations

import re
import sys
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxlc import config
from jaxlc.evaluation import heldout
from jaxlc.evaluation.protocol import _write_table, evaluate_heldout, final_checkpoints, load_rows
from jaxlc.evaluation.results import EvalError
from jaxlc.sim.reward import DECLINED, NO_GAP
from jaxlc.study.rundir import RunDir

DEFAULT = config.CONFIG_DIR / "suite.toml"
# Of a command: declined (outside env.operating_speed), no gap found, otherwise not started
# (a collision before the RL phase, or the step cap), else a lane change with one of ENDS.
FIELDS = (
    *("setting", "label", "model", "cell", "seed", "commands", "declined", "no_gap"),
    *("not_started", "lane_changes", *heldout.ENDS, "success_rate", "success_lo"),
    *("success_hi", "collision_rate", "duration_s", "peak_lat_acc", "min_ttc_s"),
)


def load(path: str | Path | None = None) -> dict[str, tuple[str, ...]]:
    """``{setting: [env] overrides}`` of a suite file (``base`` first), each checked as a
    config's values are (``heldout.in_traffic``): a bad one names its setting and key."""
    path = Path(path) if path else DEFAULT
    if not path.is_file() and (config.CONFIG_DIR / f"{path}.toml").is_file():
        path = config.CONFIG_DIR / f"{path}.toml"  # a name: eval.suite = "suite"
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as err:
        raise config.ConfigError(f"suite file '{path}': {err}") from None
    base, settings = data.get("base", []), data.get("settings", {})
    if not settings or set(data) - {"base", "settings"}:
        raise config.ConfigError(f"suite file '{path}': needs 'base' and a [settings] table only")
    out = {}
    for name, overrides in settings.items():
        out[name] = (*base, *overrides)
        try:
            heldout.in_traffic(config.Config(), out[name])
        except config.ConfigError as err:
            raise config.ConfigError(f"suite setting '{name}': {err}") from None
    return out


def _tag(name: str) -> str:
    return "suite_" + re.sub(r"[^A-Za-z0-9_.+-]", "_", name)


def _starts(path: Path) -> dict[str, int]:
    """The commands of a setting's cases (``heldout_cases.npz``) that started no lane change,
    by why: the case's own reason, the same for every policy."""
    cases = RunDir.load_npz(path)
    reason, performed = np.asarray(cases["reason"])[0], np.asarray(cases["performed"])
    before = reason[~performed]
    declined, no_gap = int((before == DECLINED).sum()), int((before == NO_GAP).sum())
    return {"declined": declined, "no_gap": no_gap, "not_started": before.size - declined - no_gap}


def run_suite(run_dir: Path, suite: str | Path | None = None, **heldout_kw: Any) -> list[dict]:
    """Every setting of ``suite`` (``load``) on ``run_dir``'s final checkpoints, with
    ``heldout_kw`` of ``evaluate_heldout``; writes ``eval/suite/suite.csv`` and ``suite.png``
    and returns the CSV's rows. A setting whose cases start too few lane changes (every
    command declined, say) gets rows of 0 lane changes and no counts."""
    rows, rd = [], RunDir(run_dir)
    for name, overrides in load(suite).items():
        try:
            result = evaluate_heldout(run_dir, traffic=overrides, tag=_tag(name), **heldout_kw)
        except EvalError as err:  # e.g. every command declined: the setting's rows say so
            print(f"suite setting '{name}': {err}", file=sys.stderr)
            metas = load_rows(run_dir, final_checkpoints(run_dir))[2]
            rows += [{**m, "setting": name, "lane_changes": 0} for m in metas]
            continue
        starts = _starts(rd.eval / f"heldout_{_tag(name)}" / rd.heldout_cases.name)
        for r in result["rows"]:
            rows.append({**r, "setting": name, "commands": result["cases"], **starts})
    rows = [{k: r.get(k) for k in FIELDS} for r in rows]
    (rd.eval / "suite").mkdir(parents=True, exist_ok=True)
    _write_table(rd.eval / "suite" / "suite.csv", rows, FIELDS)
    figure({Path(run_dir).name: rows}, rd.eval / "suite" / "suite.png")
    return rows


def figure(runs: Mapping[str, Sequence[dict]], path: Path) -> Path:
    """Success (%) by setting, each run's models side by side (a run per colour, a dot per
    model with its 95% interval; the scripted controller's rows left out)."""
    from jaxlc.evaluation.plots_io import plt, save

    names = list(dict.fromkeys(r["setting"] for rows in runs.values() for r in rows))
    fig, ax = plt.subplots(figsize=(1.2 + 1.1 * len(names), 3.6))
    width = 0.8 / max(len(runs), 1)
    for i, (run, rows) in enumerate(runs.items()):
        mine = [r for r in rows if r["model"] is not None and r["lane_changes"]]
        x = np.asarray([names.index(r["setting"]) for r in mine], float)
        x += (i + 0.5) * width - 0.4 + np.linspace(-0.3, 0.3, len(mine)) * width / max(len(mine), 1)
        y = 100 * np.asarray([r["success_rate"] for r in mine])
        lo = y - 100 * np.asarray([r["success_lo"] for r in mine])
        hi = 100 * np.asarray([r["success_hi"] for r in mine]) - y
        ax.errorbar(x, y, yerr=[lo, hi], fmt="o", ms=3, capsize=2, label=run)
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right")
    ax.set_ylabel("held-out success (%)")
    ax.legend(fontsize="small")
    return save(fig, path)
