"""The held-out suite: a run's policies driven in each of a list of named settings of the
traffic and the road (a suite file, ``configs/suite.toml``: ``base`` overrides, then each
setting's own, applied to the run's config), each setting's held-out lane changes as
``protocol.evaluate_heldout`` runs them (``eval/heldout_suite_NAME/``), gathered into
``eval/suite/suite.csv`` (a row per model and setting: the commands, those declined outside
the operating range, the lane changes, their ends and the success rate with its 95%
Clopper-Pearson interval) and ``suite.png`` (success by setting).

    python -m jaxlc.evaluate RUN --suite            # eval.suite, else configs/suite.toml
    python -m jaxlc.evaluate RUN --suite FILE.toml
    python -m jaxlc.evaluate RUN --choose [--suite]  # each model's checkpoint first (choose)
"""

from __future__ import annotations

import re
import sys
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxlc import config
from jaxlc.evaluation import heldout
from jaxlc.evaluation.numbers import write, write_csv
from jaxlc.evaluation.protocol import evaluate_heldout, final_checkpoints, load_rows
from jaxlc.evaluation.results import CHOICE, Choice, EvalError
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


def _tag(name: str, kind: str = "suite") -> str:
    return f"{kind}_" + re.sub(r"[^A-Za-z0-9_.+-]", "_", name)


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
        for r in result.rows:
            rows.append({**r.as_dict(), "setting": name, "commands": result.cases, **starts})
    rows = [{k: r.get(k) for k in FIELDS} for r in rows]
    (rd.eval / "suite").mkdir(parents=True, exist_ok=True)
    write_csv(rd.eval / "suite" / "suite.csv", rows, FIELDS)
    return rows


def choose(
    run_dir: Path,
    suite: str | Path | None,
    episodes: Sequence[int],
    lane_changes: int,
    seed: int,
    **heldout_kw: Any,
) -> Choice:
    """Each model's policy among its last checkpoint and those of ``episodes``: the one that
    fails the fewest of ``lane_changes`` held-out lane changes of seed ``seed`` (cases apart
    from those a suite judges on) in every setting of ``suite``, the later on a tie. The
    settings' evaluations go to ``eval/heldout_choice_NAME/``, the choice to
    ``eval/choice.json`` (a former one is not read while it chooses), which every later
    evaluation of the run reads (``protocol.final_checkpoints``)."""
    if not episodes:
        raise EvalError("eval.choose_episodes is []: give the episodes whose checkpoints to weigh")
    settings, failures = load(suite), {}
    for name, overrides in settings.items():
        kw = dict(lane_changes=lane_changes, seed=seed, traffic=overrides, chosen=False)
        result = evaluate_heldout(run_dir, episodes, tag=_tag(name, "choice"), **kw, **heldout_kw)
        for r in result.rows[1:]:  # the scripted row first
            by = failures.setdefault(str(r.model), {})
            by[str(r.episode)] = by.get(str(r.episode), 0) + r.lane_changes - r.success
    choice = Choice(seed, lane_changes, list(settings), least_failed(failures), failures)
    write(RunDir(run_dir).eval / CHOICE, choice)
    return choice


def least_failed(failures: dict[str, dict[str, int]]) -> dict[str, int]:
    """Per model, of its candidates' failures (``{model: {episode: failed}}``, as text), the
    episode that failed the fewest, the later of a tie."""
    return {m: int(max(by, key=lambda e: (-by[e], int(e)))) for m, by in failures.items()}
