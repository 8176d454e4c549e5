"""``python -m jaxlc.figures RUN_DIR`` (``jaxlc-figures``): the paper's figures of a run
directory, drawn by ``jaxlc.report.plots``, as files in ``RUN_DIR/figures/``.

    python -m jaxlc.figures --suite RUN_A RUN_B ... [--out FILE]

draws the held-out suite's success by setting of several runs side by side (a colour per run;
each run's ``eval/suite/suite.csv`` of ``python -m jaxlc.evaluate RUN --suite``), into
``FILE`` (default ``suite_by_config.png``); a run without its suite.csv is refused (exit 2)."""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path
from typing import Any

from jaxlc.report.plots import (  # the names the command's users and tests know it by
    fig3_returns,
    fig4_steps_loss,
    fig6_checkpoints,
    heldout_norms,
    make_all,
    profiles,
    suite_figure,
)
from jaxlc.report.plots_scenes import fig5_scenes, fig7_trajectories, learning_gif

__all__ = ["fig3_returns", "fig4_steps_loss", "fig5_scenes", "fig6_checkpoints"]
__all__ += ["fig7_trajectories", "heldout_norms", "learning_gif", "main", "make_all", "profiles"]
__all__ += ["suite_figure", "suite_rows"]


SUITE_CSV = Path("eval/suite/suite.csv")  # under a run directory (jaxlc.evaluation.suite)
SUITE_TEXT = ("setting", "label")  # the suite's text columns; the others are numbers or empty


def suite_rows(path: Path) -> list[dict[str, Any]]:
    """A suite.csv's rows with its numbers parsed (an empty field: None, as the scripted
    controller's ``model``, or a setting's counts where it started no lane change)."""

    def value(key: str, text: str) -> Any:
        if key in SUITE_TEXT or text == "":
            return text or None
        number = float(text)
        return int(number) if number.is_integer() and "." not in text else number

    with path.open(newline="") as f:
        return [{k: value(k, v) for k, v in row.items()} for row in csv.DictReader(f)]


def _suite(runs: list[Path], out: Path) -> int:
    """Each run's suite.csv side by side in ``out``; 2 (one line) where one is missing."""
    rows = {}
    for run in runs:
        if not (run / SUITE_CSV).is_file():
            print(
                f"jaxlc-figures: {run / SUITE_CSV} not found (python -m jaxlc.evaluate "
                f"{run} --suite writes it)",
                file=sys.stderr,
            )
            return 2
        rows[run.name if run.name not in rows else str(run)] = suite_rows(run / SUITE_CSV)
    print(suite_figure(rows, out))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="jaxlc-figures",
        description="Write the paper's figures of a run directory (trained with python -m "
        "jaxlc.sweep; the evaluation's figures need python -m jaxlc.evaluate first) to "
        "RUN_DIR/figures/ and print each file written.",
    )
    parser.add_argument("run_dir", type=Path, nargs="+", help="run directory of jaxlc.sweep")
    parser.add_argument(
        "--suite", action="store_true", help="the runs' held-out suites side by side (several)"
    )
    parser.add_argument("--out", type=Path, default=Path("suite_by_config.png"), help="--suite")
    args = parser.parse_args(argv)  # --help: usage, exit 0; unknown arguments: exit 2
    if args.suite:
        return _suite(args.run_dir, args.out)
    if len(args.run_dir) > 1:
        parser.error("several run directories are for --suite")
    args.run_dir = args.run_dir[0]
    if not args.run_dir.is_dir():
        parser.error(f"run_dir: {args.run_dir} is not a directory")
    for path in make_all(args.run_dir):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
