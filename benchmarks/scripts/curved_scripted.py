"""The scripted controller on curved roads: does the road frame make a curve drivable?

For each road curvature (1/m; > 0 bends toward the higher lanes) the held-out lane changes of
``jaxlc.evaluation`` (``cases_for_lane_changes``' keys: the fewest held-out keys whose cases hold
``--lane-changes`` lane changes) are driven by the scripted controller
(``jaxlc.sim.controller.scripted_action``, the policy ``None`` of ``evaluate_policies``), and
their ends are counted with ``jaxlc.evaluation.heldout.model_row``. Beside them: the first RL
observation's offset from the target lane's centre line (one lane width on a straight road)
and the curvature the observation reports.

    python benchmarks/scripts/curved_scripted.py --curvatures -0.002 0 0.002 --lane-changes 1000 \
        --out benchmarks/curved_scripted

Writes ``OUT/curved_scripted.csv`` and prints it.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # run as a script from anywhere, without installing jaxlc
    sys.path.insert(0, str(ROOT))

from csvfile import write_csv  # noqa: E402

from jaxlc import config  # noqa: E402
from jaxlc.evaluation import heldout  # noqa: E402
from jaxlc.evaluation.cases import cases_for_lane_changes, evaluate_policies, programs  # noqa: E402
from jaxlc.sim.env import EnvParams  # noqa: E402
from jaxlc.sim.observation import INDEX, scale  # noqa: E402

FIELDS = (
    "curvature",
    "cases",
    "lane_changes",
    "success",
    "out_of_bounds",
    "collision",
    "timeout",
    "unfinished",
    "success_rate",
    "success_lo",
    "failure_bound",
    "first_offset_min_m",
    "first_offset_max_m",
    "obs_curvature",
    "duration_s",
    "peak_lat_acc",
    "wall_s",
)
MAX_STEPS = 1500  # the held-out evaluation's


def measure(cfg: config.Config, lane_changes: int, seed: int) -> dict:
    """One curvature's row: the scripted controller on ``lane_changes`` held-out lane changes."""
    t0 = time.time()
    keys, _ = cases_for_lane_changes(cfg, lane_changes, seed=seed, max_steps=MAX_STEPS)
    out, _, info = evaluate_policies(cfg, [None], [1], keys=keys, traced=0, max_steps=MAX_STEPS)
    row = heldout.model_row(out, info, 0, cfg.env.dt)
    # The first RL observation of every case (the start program is cached: no recompile).
    start, _ = programs(cfg, MAX_STEPS)
    cs = start(keys)
    p = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    perf = np.asarray(cs.performed)
    obs = np.asarray(cs.obs)[perf]
    offset = np.abs(obs[:, INDEX["offset"]] * float(scale("offset", p)))
    kappa = obs[:, INDEX["curvature"]] * float(scale("curvature", p))
    return {
        "cases": len(keys),
        **row,
        "first_offset_min_m": float(offset.min()),
        "first_offset_max_m": float(offset.max()),
        "obs_curvature": float(np.unique(kappa.round(9))[0]) if len(np.unique(kappa)) == 1 else "",
        "wall_s": round(time.time() - t0, 1),
    }


def _short(v):
    """Floats to 6 significant digits: float32 values and means print their noise otherwise."""
    return float(f"{v:.6g}") if isinstance(v, float) else v


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser()
    ap.add_argument("--curvatures", type=float, nargs="+", default=[-0.002, 0.0, 0.002])
    ap.add_argument("--lane-changes", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0, help="held-out key stream")
    ap.add_argument("--config", type=Path, default=config.DEFAULT_CONFIG)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    base = config.load(args.config)
    rows = []
    for kappa in args.curvatures:
        cfg = dataclasses.replace(base, env=dataclasses.replace(base.env, curvature=kappa))
        cfg = config.from_dict(cfg.to_dict())  # validated like any config
        rows.append({"curvature": kappa, **measure(cfg, args.lane_changes, args.seed)})
        r = rows[-1]
        print(
            f"curvature {kappa:+g}: {r['success']}/{r['lane_changes']} succeed, first offset "
            f"{r['first_offset_min_m']:.3f}-{r['first_offset_max_m']:.3f} m, {r['wall_s']} s",
            flush=True,
        )
    if args.out is not None:
        path = args.out / "curved_scripted.csv"
        write_csv(path, ({k: _short(v) for k, v in r.items()} for r in rows), FIELDS)
        print(path.read_text())
    return rows


if __name__ == "__main__":
    main()
