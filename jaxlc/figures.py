"""``python -m jaxlc.figures RUN_DIR`` (``jaxlc-figures``): the paper's figures of a run
directory, drawn by ``jaxlc.report.plots``, as files in ``RUN_DIR/figures/``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from jaxlc.report.plots import (  # the names the command's users and tests know it by
    fig3_returns,
    fig4_steps_loss,
    fig6_checkpoints,
    heldout_norms,
    make_all,
    profiles,
)
from jaxlc.report.plots_scenes import fig5_scenes, fig7_trajectories, learning_gif

__all__ = ["fig3_returns", "fig4_steps_loss", "fig5_scenes", "fig6_checkpoints"]
__all__ += ["fig7_trajectories", "heldout_norms", "learning_gif", "main", "make_all", "profiles"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="jaxlc-figures",
        description="Write the paper's figures of a run directory (trained with python -m "
        "jaxlc.sweep; the evaluation's figures need python -m jaxlc.evaluate first) to "
        "RUN_DIR/figures/ and print each file written.",
    )
    parser.add_argument("run_dir", type=Path, help="run directory of jaxlc.sweep")
    args = parser.parse_args(argv)  # --help: usage, exit 0; unknown arguments: exit 2
    if not args.run_dir.is_dir():
        parser.error(f"run_dir: {args.run_dir} is not a directory")
    for path in make_all(args.run_dir):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
