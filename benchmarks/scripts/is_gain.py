"""How much an IS proposal gains over crude Monte Carlo, measured on crude MC's own failures.

IS's relative half-width comes from its weighted sample; a failure path that the proposal draws
less often than the traffic does weighs more than 1, and where such paths are rare the sample
holds few or none of them and understates the variance. Crude MC's failures are a sample of
every failure path at the traffic's own frequencies, so each one's weight under a proposal
gives the IS estimator's variance per lane change without that blind spot:
``Var_q(w 1_F) = P E_p[w | F] - P^2`` against crude MC's ``P (1 - P)``, a gain of
``(1 - P) / (E_p[w | F] - P)``, with ``w = p / (a p + (1 - a) q)`` (the defensive mixture at
the IS run's share ``a``, or ``--defensive``'s: the same replays weighed as a mixture of
another share would weigh them). Each failure is replayed from its case key on the traffic's own
draws through the tilted program (a nominal chunk: the draws untilted, the ratio taken against
the proposal); the interval is a 95% bootstrap over the failures.

    python benchmarks/scripts/is_gain.py RUN --mc DIR --is DIR [DIR ...] --out gain.json

``--mc``: crude MC's ``validate`` folder (its ``validate.json``, and ``failures.json``: the
case indices of its failures of one kind, from its ``cases.json``); ``--is``: IS folders of
the same setting (their ``validate.json``: proposal, defensive share; a mixture of one-role
tilts, ``--family mixture``, weighs each failure from its step statistics as its run did).
``RUN``: the run directory they validated (``--model`` as ``python -m jaxlc.validate``'s).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.evaluation import heldout, proposal, rare, validation
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation.cases import columns
from jaxlc.evaluation.mixture import Mixture
from jaxlc.sim.env import EnvParams
from jaxlc.validate import model_rows

BOOTSTRAP = 2000


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--model", default="scripted")
    ap.add_argument("--mc", type=Path, required=True)
    ap.add_argument("--is", dest="is_dirs", type=Path, nargs="+", required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument(
        "--defensive", type=float, default=None, help="mixture share (default: each IS run's)"
    )
    args = ap.parse_args(argv)
    mc = json.loads((args.mc / "validate.json").read_text())
    fail = json.loads((args.mc / "failures.json").read_text())
    p_hat = mc["models"][0]["estimates"][fail["kind"]]["estimate"]
    cfg, rows = model_rows(args.run_dir, args.model)
    cfg = heldout.in_traffic(cfg, mc["traffic_overrides"])
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    run = validation.program(cfg, mc["max_steps"], True)
    pol = validation.policies(cfg, rows[0]["actor"], rows[0]["k"])
    col = validation.KINDS.index(fail["kind"])
    keys = streams.stream(mc["seed"], streams.VALIDATE, fail["cases"])
    n, chunk = keys.shape[0], mc["chunk"]  # crude MC's chunk: its program, its shapes
    keys = jnp.concatenate([keys, jnp.broadcast_to(keys[:1], (-n % chunk, 2))])
    rng = np.random.default_rng(0)
    gain = lambda m: float((1 - p_hat) / (m - p_hat))  # noqa: E731
    result = {"mc": str(args.mc), "kind": fail["kind"], "failures": len(fail["cases"])}
    result |= {"mc_estimate": p_hat, "proposals": []}
    for d in args.is_dirs:
        model = json.loads((d / "validate.json").read_text())["models"][0]
        a = model["defensive"] if args.defensive is None else args.defensive
        mix = None
        if model["proposal"].get("family") == "mixture":  # its weights from the statistics
            mix = Mixture.from_dict(model["proposal"])  # the shares its chunks were drawn in
            mix = dataclasses.replace(mix, alpha=mix.alpha if args.defensive is None else a)
            replay = mix.component(base, -1)
        else:  # the traffic's own draws, their ratio taken against the proposal
            replay = proposal.from_dict({**model["proposal"], "drawn_nominal": 1.0})
        outs = [
            columns(jax.device_get(run(replay, pol, keys[lo : lo + chunk])[0]))
            for lo in range(0, keys.shape[0], chunk)
        ]
        failed = np.concatenate([validation.kinds(o, base.dt)[:, col] for o in outs])[:n]
        assert failed.all(), "a replay differs from crude MC's"
        if mix is None:
            log_w = np.concatenate([o["log_w"][0] for o in outs])[:n].astype(np.float64)  # p/q
            w = np.exp(rare.defensive(log_w, a))  # p / (a p + (1 - a) q)
        else:
            w = np.exp(mix.log_weight(np.concatenate([o["tilt"][0] for o in outs])[:n]))
        boot = rng.choice(w, (BOOTSTRAP, w.size)).mean(axis=1)
        lo, hi = np.quantile(boot, [0.025, 0.975])
        row = {
            "is": str(d),
            "defensive": a,
            "mean_weight_given_failure": round(float(w.mean()), 4),
            "mean_weight_lo": round(float(lo), 4),
            "mean_weight_hi": round(float(hi), 4),
            "gain": round(gain(w.mean()), 2),
            "gain_lo": round(gain(hi), 2),
            "gain_hi": round(gain(lo), 2),
            "failures_weighing_over_1": int((w > 1).sum()),
            "their_share_of_the_mean": round(float(w[w > 1].sum() / w.sum()), 3),
            "largest_weight": round(float(w.max()), 3),
        }
        print(row, flush=True)
        result["proposals"].append(row)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
