"""Which proposal family could gain 10x in this setting: crude MC's timeouts split in two halves,
a proposal fitted on one half, its gain measured on the other.

    python benchmarks/validate_rare_cpu_2026-11-27/families.py RUN --out families.json

``RUN``: the run directory ``mc/`` validated (``--model scripted`` reads only its config).
Crude MC's failures are a sample of the failure paths at the traffic's own frequencies, so a
proposal's gain over crude MC is ``(1 - P) / (E_p[w | F] - P)`` with ``w`` the defensive
mixture's weight of each failure replayed from its key (``is_gain.py``). Two families:

- ``single``: one proposal (``jaxlc.evaluation.proposal``), braking tilted from one window;
  fitted as the cross-entropy method's limit, the maximum-likelihood fit to the failures
  themselves (``validation._fit`` with unit weights: the CE's elite is the failures, weighed
  to the traffic's own distribution, which crude MC's are drawn from); each half's fit
  weighed on the other half by the tilted program's exact ratios.
- ``mixture``: a mixture of proposals that each tilt one role's braking (the target lane's
  lead, the own lane's leader, the others ahead) from one window (acceptance or entry), the
  deceleration and duration untilted; rates and shares fitted to the least mean weight of one
  half (Nelder-Mead), scored on the other. A one-role tilt's log ratio is a function of the
  step statistics (``proposal.STATS``), checked here against the program's on every
  component fitted.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

from jaxlc.evaluation import heldout, proposal, rare, validation
from jaxlc.evaluation.cases import columns
from jaxlc.sim.braking import start_probability
from jaxlc.sim.env import EnvParams
from jaxlc.validate import model_rows

HERE = Path(__file__).resolve().parent
MIXED_ROLES = ("lead", "own_leader", "ahead")
MIXED_WINDOWS = ("acceptance", "entry")
STAT = {name: i for i, name in enumerate(proposal.STATS)}


def one_role_log_w(st: np.ndarray, role: str, q: float, p: float) -> np.ndarray:
    """``log p/q`` of each path when only ``role``'s braking is tilted, to ``q`` per step."""
    ev, tr = st[:, STAT[f"brake_events_{role}"]], st[:, STAT[f"brake_trials_{role}"]]
    return ev * np.log(p / q) + (tr - ev) * (np.log1p(-p) - np.log1p(-q))


def _rate(log_q: float, p: float) -> float:
    with np.errstate(over="ignore"):  # a rate far above the clip
        return float(np.clip(np.exp(log_q), p, 0.5))


def mixture_weight(z: np.ndarray, st: dict, idx: np.ndarray, p: float, a: float) -> np.ndarray:
    """Each path's weight under the defensive mixture of the one-role tilts: ``z`` holds the
    log rates (held to [p, 0.5]: a tilt raises a rate, as the CE's does), then the log shares
    (unnormalised), one per component."""
    comps = [(r, w) for w in MIXED_WINDOWS for r in MIXED_ROLES]
    share = np.exp(z[len(comps) :] - np.logaddexp.reduce(z[len(comps) :]))
    inv = sum(
        share[k] * np.exp(-one_role_log_w(st[w][idx], r, _rate(z[k], p), p))
        for k, (r, w) in enumerate(comps)
    )
    return 1.0 / (a + (1.0 - a) * inv)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--mc", type=Path, default=HERE / "mc")
    ap.add_argument("--defensive", type=float, default=validation.DEFENSIVE_SHARE)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    mc = json.loads((args.mc / "validate.json").read_text())
    fail = json.loads((args.mc / "failures.json").read_text())
    big_p = mc["models"][0]["estimates"][fail["kind"]]["estimate"]
    cfg, rows = model_rows(args.run_dir, "scripted")
    cfg = heldout.in_traffic(cfg, mc["traffic_overrides"])
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    run = validation.program(cfg, mc["max_steps"], True)
    pol = validation.policies(cfg, None, 1)
    col = validation.KINDS.index(fail["kind"])
    keys = validation.keys_at(mc["seed"], validation.VALIDATE_TAG, fail["cases"])
    n, chunk = keys.shape[0], mc["chunk"]
    keys = jnp.concatenate([keys, jnp.broadcast_to(keys[:1], (-n % chunk, 2))])
    p, a = float(start_probability(base)), args.defensive

    def replay(q: proposal.Proposal) -> tuple[np.ndarray, np.ndarray]:
        """``(log_w, stats)`` of the failures on the traffic's own draws, against ``q``."""
        q = q.replace(drawn_nominal=jnp.float32(1.0))
        outs = [
            columns(jax.device_get(run(q, pol, keys[lo : lo + chunk])[0]))
            for lo in range(0, keys.shape[0], chunk)
        ]
        failed = np.concatenate([validation.kinds(o, base.dt)[:, col] for o in outs])[:n]
        assert failed.all(), "a replay differs from crude MC's"
        log_w = np.concatenate([o["log_w"][0] for o in outs])[:n].astype(np.float64)
        return log_w, np.concatenate([o["tilt"][0] for o in outs])[:n].astype(np.float64)

    def gain(w: np.ndarray) -> float:
        return round(float((1 - big_p) / (w.mean() - big_p)), 2)

    def mixed(log_w: np.ndarray) -> np.ndarray:
        return np.exp(rare.defensive(log_w, a))

    halves = (np.arange(n)[0::2], np.arange(n)[1::2])
    windows = {w: float(proposal.TILT_FROM.index(w)) for w in proposal.TILT_FROM}
    st = {w: replay(proposal.nominal(base).replace(tilt_from=jnp.float32(t)))[1]
          for w, t in windows.items()}  # fmt: skip
    result = {"mc": str(args.mc), "kind": fail["kind"], "failures": n, "mc_estimate": big_p}
    result |= {"defensive": a, "single": [], "mixture": {}}
    events = {
        w: np.stack([st[w][:, STAT[f"brake_events_{r}"]] for r in proposal.ROLES], 1) > 0
        for w in windows
    }  # (failures, roles) each: met a braking event of the role in the window
    late = ~events["acceptance"].any(axis=1)  # none after the gap's acceptance
    result["no_braking_after_acceptance"] = {
        "failures": int(late.sum()),
        "with_braking_from_entry": int(events["entry"][late].any(axis=1).sum()),
        "by_role_from_entry": dict(
            zip(proposal.ROLES, events["entry"][late].sum(axis=0).tolist(), strict=True)
        ),
    }
    for w, t in windows.items():
        row = {"window": w, "folds": []}
        for fit_on, score_on in (halves, halves[::-1]):
            q = validation._fit(np.ones(fit_on.size), st[w][fit_on], p).replace(
                tilt_from=jnp.float32(t)
            )
            log_w, _ = replay(q)
            row["folds"].append({"proposal": q.to_dict(), "gain": gain(mixed(log_w[score_on]))})
        print(row["window"], [f["gain"] for f in row["folds"]], flush=True)
        result["single"].append(row)
    comps = [(r, w) for w in MIXED_WINDOWS for r in MIXED_ROLES]
    z0 = np.concatenate([np.full(len(comps), np.log(0.005)), np.zeros(len(comps))])

    def fit(idx: np.ndarray) -> np.ndarray:
        res = scipy.optimize.minimize(
            lambda z: mixture_weight(z, st, idx, p, a).mean(),
            z0,
            method="Nelder-Mead",
            options={"maxiter": 20_000, "maxfev": 20_000},
        )
        return res.x

    folds, worst = [], 0.0
    for fit_on, score_on in (halves, halves[::-1]):
        z = fit(fit_on)
        for k, (r, w) in enumerate(comps):  # the statistics' ratio against the program's
            one = proposal.nominal(base).replace(tilt_from=jnp.float32(windows[w]))
            one = one.replace(brake=one.brake.at[proposal.ROLES.index(r)].set(_rate(z[k], p)))
            exact, _ = replay(one)
            worst = max(
                worst, float(np.abs(exact - one_role_log_w(st[w], r, _rate(z[k], p), p)).max())
            )
        share = np.exp(z[len(comps) :] - np.logaddexp.reduce(z[len(comps) :]))
        folds.append(
            {
                "rates": {f"{r}@{w}": _rate(z[k], p) for k, (r, w) in enumerate(comps)},
                "shares": {
                    f"{r}@{w}": round(float(s), 3) for (r, w), s in zip(comps, share, strict=True)
                },
                "gain": gain(mixture_weight(z, st, score_on, p, a)),
                "gain_on_its_own_half": gain(mixture_weight(z, st, fit_on, p, a)),
            }
        )
        print("mixture", folds[-1]["gain"], folds[-1]["gain_on_its_own_half"], flush=True)
    result["mixture"] = {"folds": folds, "largest_log_w_difference": worst}
    assert worst < 1e-3, worst
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
