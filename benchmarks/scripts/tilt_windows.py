"""Which ``--tilt-from`` window holds the braking a policy's failures met: each failing lane
change of a run's model on the traffic's own draws (the nominal proposal, every weight 1),
with the braking events around the ego (``proposal.ROLES``) counted from the gap's acceptance,
from the command and from the ego's entry.

    python benchmarks/scripts/tilt_windows.py RUN --model 3 --kind timeout --chunks 50 \
        --out windows.csv --traffic env.braking=true env.braking_rate=5
    python benchmarks/scripts/tilt_windows.py RUN --model 3 --kind collision \
        --cases 1136125 2141183 --out collisions.csv --traffic env.braking=true env.braking_rate=5

The cases are those of ``python -m jaxlc.validate --seed 0``'s estimate (the first ``--chunks``
chunks of ``--chunk``, or the chunks holding ``--cases``). Writes one row per failing lane
change of ``--kind``: its index, its end, a collision's partner and hazard, and per window the
braking events started by role and the sums of their deceleration and duration draws (each in
[0, 1) of its range); prints, per window, how many of the failures met no event.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from csvfile import write_csv

from jaxlc import config
from jaxlc.evaluation import heldout, proposal, validation
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation.cases import columns
from jaxlc.evaluation.results import OUTCOMES
from jaxlc.evaluation.safety import HAZARDS, PARTNERS
from jaxlc.sim.env import EnvParams
from jaxlc.validate import model_rows


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--model", default="④")
    ap.add_argument("--kind", choices=validation.KINDS, default="collision")
    ap.add_argument("--chunks", type=int, default=1)
    ap.add_argument("--cases", type=int, nargs="+", default=None, help="case indices instead")
    ap.add_argument("--chunk", type=int, default=2048)
    ap.add_argument("--traffic", nargs="+", default=[], metavar="env.KEY=VALUE")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    cfg, rows = model_rows(args.run_dir, args.model)
    cfg = heldout.in_traffic(cfg, args.traffic)
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    run = validation.program(cfg, config.EvalConfig().max_steps, True)
    pol = validation.policies(cfg, rows[0]["actor"], rows[0]["k"])
    col = validation.KINDS.index(args.kind)
    if args.cases:
        starts = sorted({c // args.chunk * args.chunk for c in args.cases})
    else:
        starts = [i * args.chunk for i in range(args.chunks)]
    found, lane_changes = [], 0
    for lo in starts:
        keys = streams.stream(0, streams.VALIDATE, range(lo, lo + args.chunk))
        by_window = []
        for w in range(len(proposal.TILT_FROM)):
            nom = proposal.nominal(base).replace(tilt_from=jnp.float32(w))
            by_window.append(columns(jax.device_get(run(nom, pol, keys)[0])))
        out = by_window[0]  # the same lane changes in every window (nominal draws)
        perf = out["performed"][0]
        lane_changes += int(perf.sum())
        hit = perf & validation.kinds(out, base.dt)[:, col]
        for i in np.nonzero(hit)[0]:
            if args.cases and lo + i not in args.cases:
                continue
            row = {
                "case": lo + int(i),
                "end": OUTCOMES[int(out["reason"][0][i])],
                "partner": PARTNERS[int(out["partner"][0][i])],
                "hazard": HAZARDS[int(out["hit_hazard"][0][i])],
                "manoeuvre_steps": int(out["steps"][0][i]),
            }
            for name, o in zip(proposal.TILT_FROM, by_window, strict=True):
                tilt = dict(zip(proposal.STATS, o["tilt"][0][i], strict=True))  # by name
                for role in proposal.ROLES:
                    row[f"{name}_events_{role}"] = int(tilt[f"brake_events_{role}"])
                row[f"{name}_decel_u_sum"] = np.round(tilt["brake_acc_sum"], 3)
                row[f"{name}_time_u_sum"] = np.round(tilt["brake_time_sum"], 3)
            found.append(row)
    write_csv(args.out, found, list(found[0]) if found else ["case"])
    print(f"{len(found)} {args.kind} in {lane_changes} lane changes of {len(starts)} chunks")
    for name in proposal.TILT_FROM:
        none = sum(all(r[f"{name}_events_{x}"] == 0 for x in proposal.ROLES) for r in found)
        print(f"from the {name}: {none} of {len(found)} met no braking event around the ego")
    return found


if __name__ == "__main__":
    main()
