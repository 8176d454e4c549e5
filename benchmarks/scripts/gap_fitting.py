"""The gap-fitting controller against the scripted baseline on held-out lane changes.

``jaxlc.sim.controller.fitting_action`` holds the origin lane, and adjusts its speed, until the
accepted gap fits the 0.9 s headway norm with a margin; ``scripted_action`` (the held-out
evaluation's baseline row) changes lane as soon as the gap is accepted. Both run on the same
held-out cases (``cases_for_lane_changes``, the evaluation's own key stream) under each config
given, with the manoeuvre time unobserved (the config as it is) and observed
(``env.terminal_timeout = true``, which the controller's fallback after ``FIT_GO_AFTER`` s
reads), and their held-out rows (``jaxlc.evaluation.heldout.model_row``) are written.
Nothing is trained: it asks whether control alone, with the default's gap acceptance, can keep
lane changes inside every norm, and at what cost in success.

Usage: ``python benchmarks/scripts/gap_fitting.py [--configs configs/joint.toml ...]
[--seeds 0 1] [--lane-changes 1000] [--out benchmarks/gap_fitting_probe]``; writes
``results.csv`` and ``results.json`` there.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # run as a script from anywhere, without installing jaxlc
    sys.path.insert(0, str(ROOT))


from csvfile import write_csv  # noqa: E402

from jaxlc import config  # noqa: E402
from jaxlc.evaluation import cases, heldout  # noqa: E402
from jaxlc.sim.controller import fitting_action, scripted_action  # noqa: E402
from jaxlc.sim.env import EnvParams  # noqa: E402

CONTROLLERS = {"scripted": scripted_action, "fitting": fitting_action}
FIELDS = (
    "config", "time_observed", "seed", "controller", "lane_changes", "success", "collision",
    "timeout", "out_of_bounds", "norm_all", "norm_min_thw_s", "norm_min_ttc_s", "norm_lcm_s",
    "norm_peak_lat_acc", "norm_peak_lat_jerk", "thw_crit_lead", "thw_crit_lag", "lcm_start_s",
    "duration_s", "peak_long_acc", "seconds",
)  # fmt: skip


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--configs", nargs="+", default=["configs/joint.toml", "configs/default.toml"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1], help="held-out key seeds")
    ap.add_argument("--lane-changes", type=int, default=1000)
    ap.add_argument("--max-steps", type=int, default=1500)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "gap_fitting_probe")
    return ap.parse_args(argv)


def rows_for(
    path: str, time_observed: bool, seed: int, lane_changes: int, max_steps: int
) -> list[dict]:
    """Both controllers' held-out rows under one config, time observed or not, on one seed's
    held-out cases."""
    overrides = ["env.terminal_timeout=true"] if time_observed else []
    cfg = config.load(path, overrides)
    p = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    _, started = cases.cases_for_lane_changes(cfg, lane_changes, seed, max_steps)
    info = cases.case_info(started, cfg)
    rows = []
    for name, controller in CONTROLLERS.items():
        t0 = time.perf_counter()
        out = cases.evaluate_act(
            cfg, lambda o, c=controller: c(o, p), started=started, max_steps=max_steps
        )
        row = heldout.model_row(out, info, 0, float(p.dt))  # out: (1, cases) arrays
        rows.append(
            {
                "config": path,
                "time_observed": time_observed,
                "seed": seed,
                "controller": name,
                **{k: row[k] for k in FIELDS[4:-1]},
                "seconds": round(time.perf_counter() - t0, 1),
            }
        )
        print({k: rows[-1][k] for k in FIELDS[:10]}, flush=True)
    return rows


def main(argv: list[str] | None = None) -> list[dict]:
    args = parse_args(argv)
    rows = [
        row
        for path in args.configs
        for observed in (False, True)
        for seed in args.seeds
        for row in rows_for(path, observed, seed, args.lane_changes, args.max_steps)
    ]
    write_csv(args.out / "results.csv", rows, FIELDS)
    (args.out / "results.json").write_text(json.dumps(rows, indent=1) + "\n")
    return rows


if __name__ == "__main__":
    main()
