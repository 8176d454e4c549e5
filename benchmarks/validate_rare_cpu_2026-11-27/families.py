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
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation.cases import columns
from jaxlc.sim.braking import start_probability
from jaxlc.sim.env import EnvParams
from jaxlc.validate import model_rows

HERE = Path(__file__).resolve().parent
MIXED_ROLES = ("lead", "own_leader", "ahead")
MIXED_WINDOWS = ("acceptance", "entry")
COMPONENTS = [(r, w) for w in MIXED_WINDOWS for r in MIXED_ROLES]  # the mixture's (role, window)
STAT = {name: i for i, name in enumerate(proposal.STATS)}


def one_role_log_w(st: np.ndarray, role: str, q: float, p: float) -> np.ndarray:
    """``log p/q`` of each path when only ``role``'s braking is tilted, to ``q`` per step."""
    ev, tr = st[:, STAT[f"brake_events_{role}"]], st[:, STAT[f"brake_trials_{role}"]]
    return ev * np.log(p / q) + (tr - ev) * (np.log1p(-p) - np.log1p(-q))


def _rate(log_q: float, p: float) -> float:
    with np.errstate(over="ignore"):  # a rate far above the clip
        return float(np.clip(np.exp(log_q), p, 0.5))


def _shares(z: np.ndarray) -> np.ndarray:
    """The mixture's shares from ``z``'s unnormalised log shares (its second half)."""
    logs = z[len(COMPONENTS) :]
    return np.exp(logs - np.logaddexp.reduce(logs))


def mixture_weight(z: np.ndarray, st: dict, idx: np.ndarray, p: float, a: float) -> np.ndarray:
    """Each path's weight under the defensive mixture of the one-role tilts: ``z`` holds the
    log rates (held to [p, 0.5]: a tilt raises a rate, as the CE's does), then the log shares
    (unnormalised), one per component."""
    share = _shares(z)
    inv = sum(
        share[k] * np.exp(-one_role_log_w(st[w][idx], r, _rate(z[k], p), p))
        for k, (r, w) in enumerate(COMPONENTS)
    )
    return 1.0 / (a + (1.0 - a) * inv)


class Failures:
    """Crude MC's failures of one kind, replayed from their keys on the traffic's own draws."""

    def __init__(self, run_dir: Path, mc_dir: Path):
        mc = json.loads((mc_dir / "validate.json").read_text())
        fail = json.loads((mc_dir / "failures.json").read_text())
        self.kind, self.estimate = (
            fail["kind"],
            mc["models"][0]["estimates"][fail["kind"]]["estimate"],
        )
        cfg, _ = model_rows(run_dir, "scripted")
        cfg = heldout.in_traffic(cfg, mc["traffic_overrides"])
        self.base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
        self.p = float(start_probability(self.base))
        self.run = validation.program(cfg, mc["max_steps"], True)
        self.pol = validation.policies(cfg, None, 1)
        keys = streams.stream(mc["seed"], streams.VALIDATE, fail["cases"])
        self.n, self.chunk = keys.shape[0], mc["chunk"]  # crude MC's chunk: its program
        self.keys = jnp.concatenate([keys, jnp.broadcast_to(keys[:1], (-self.n % self.chunk, 2))])

    def replay(self, q: proposal.Proposal) -> tuple[np.ndarray, np.ndarray]:
        """``(log_w, stats)`` of the failures, ``(n,)`` and ``(n, STATS)``, against ``q``."""
        q = q.replace(drawn_nominal=jnp.float32(1.0))
        outs = [
            columns(jax.device_get(self.run(q, self.pol, self.keys[lo : lo + self.chunk])[0]))
            for lo in range(0, self.keys.shape[0], self.chunk)
        ]
        col = validation.KINDS.index(self.kind)
        failed = np.concatenate([validation.kinds(o, self.base.dt)[:, col] for o in outs])
        assert failed[: self.n].all(), "a replay differs from crude MC's"
        log_w = np.concatenate([o["log_w"][0] for o in outs])[: self.n].astype(np.float64)
        return log_w, np.concatenate([o["tilt"][0] for o in outs])[: self.n].astype(np.float64)

    def window(self, name: str) -> proposal.Proposal:
        """The traffic's own distribution, braking counted from window ``name``."""
        return proposal.nominal(self.base).replace(
            tilt_from=jnp.float32(proposal.TILT_FROM.index(name))
        )

    def gain(self, w: np.ndarray) -> float:
        """Gain over crude MC of a proposal whose failures weigh ``w``."""
        return round(float((1 - self.estimate) / (w.mean() - self.estimate)), 2)


def untilted_from_acceptance(st: dict[str, np.ndarray]) -> dict:
    """The failures with no braking event around the ego after the gap's acceptance, and the
    roles of the events they met from the entry."""
    events = {
        w: np.stack([st[w][:, STAT[f"brake_events_{r}"]] for r in proposal.ROLES], 1) > 0
        for w in st
    }  # (failures, roles) each: met a braking event of the role in the window
    late = ~events["acceptance"].any(axis=1)
    return {
        "failures": int(late.sum()),
        "with_braking_from_entry": int(events["entry"][late].any(axis=1).sum()),
        "by_role_from_entry": dict(
            zip(proposal.ROLES, events["entry"][late].sum(axis=0).tolist(), strict=True)
        ),
    }


def single(fs: Failures, st: dict[str, np.ndarray], halves: tuple, a: float) -> list[dict]:
    """Per window, one proposal fitted on each half as the CE's limit, weighed on the other."""
    rows = []
    for w in proposal.TILT_FROM:
        row = {"window": w, "folds": []}
        for fit_on, score_on in (halves, halves[::-1]):
            q = validation._fit(np.ones(fit_on.size), st[w][fit_on], fs.p)
            q = q.replace(tilt_from=fs.window(w).tilt_from)
            log_w, _ = fs.replay(q)
            w_out = np.exp(rare.defensive(log_w[score_on], a))
            row["folds"].append({"proposal": q.to_dict(), "gain": fs.gain(w_out)})
        print(row["window"], [f["gain"] for f in row["folds"]], flush=True)
        rows.append(row)
    return rows


def mixture(fs: Failures, st: dict[str, np.ndarray], halves: tuple, a: float) -> dict:
    """The mixture of one-role tilts fitted on each half, weighed on the other; each
    component's ratio from the statistics checked against the program's."""
    n_comp = len(COMPONENTS)
    z0 = np.concatenate([np.full(n_comp, np.log(0.005)), np.zeros(n_comp)])
    folds, worst = [], 0.0
    for fit_on, score_on in (halves, halves[::-1]):
        z = scipy.optimize.minimize(
            lambda z, idx=fit_on: mixture_weight(z, st, idx, fs.p, a).mean(),
            z0,
            method="Nelder-Mead",
            options={"maxiter": 20_000, "maxfev": 20_000},
        ).x
        for k, (r, w) in enumerate(COMPONENTS):
            q = _rate(z[k], fs.p)
            one = fs.window(w)
            exact, _ = fs.replay(one.replace(brake=one.brake.at[proposal.ROLES.index(r)].set(q)))
            worst = max(worst, float(np.abs(exact - one_role_log_w(st[w], r, q, fs.p)).max()))
        share = _shares(z)
        names = [f"{r}@{w}" for r, w in COMPONENTS]
        folds.append(
            {
                "rates": {c: _rate(z[k], fs.p) for k, c in enumerate(names)},
                "shares": {c: round(float(s), 3) for c, s in zip(names, share, strict=True)},
                "gain": fs.gain(mixture_weight(z, st, score_on, fs.p, a)),
                "gain_on_its_own_half": fs.gain(mixture_weight(z, st, fit_on, fs.p, a)),
            }
        )
        print("mixture", folds[-1]["gain"], folds[-1]["gain_on_its_own_half"], flush=True)
    assert worst < 1e-3, worst
    return {"folds": folds, "largest_log_w_difference": worst}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--mc", type=Path, default=HERE / "mc")
    ap.add_argument("--defensive", type=float, default=validation.DEFENSIVE_SHARE)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    fs, a = Failures(args.run_dir, args.mc), args.defensive
    halves = (np.arange(fs.n)[0::2], np.arange(fs.n)[1::2])
    st = {w: fs.replay(fs.window(w))[1] for w in proposal.TILT_FROM}  # (n, STATS) each
    result = {"mc": str(args.mc), "kind": fs.kind, "failures": fs.n, "mc_estimate": fs.estimate}
    result |= {"defensive": a, "no_braking_after_acceptance": untilted_from_acceptance(st)}
    result |= {"single": single(fs, st, halves, a), "mixture": mixture(fs, st, halves, a)}
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
