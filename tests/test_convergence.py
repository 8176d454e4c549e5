"""Learning-speed measures on hand-made training curves, and the paper's comparisons on them."""

from __future__ import annotations

import numpy as np
import pytest

from jaxlc.evaluation import convergence
from jaxlc.sim.reward import OUT_OF_BOUNDS, SUCCESS


def _curves(switch: int, n: int = 2000, noise: float = 0.0, seed: int = 0) -> dict:
    """A model that fails (return -2000, 3 steps) until ``switch``, then succeeds (return
    -130, 45 steps)."""
    rng = np.random.default_rng(seed)
    learnt = np.arange(n) >= switch
    ret = np.where(learnt, -130.0, -2000.0) + noise * rng.standard_normal(n)
    return {
        "ret": ret,
        "steps": np.where(learnt, 45, 3),
        "reason": np.where(learnt, SUCCESS, OUT_OF_BOUNDS),
    }


def test_a_step_change_converges_where_the_window_has_crossed_it() -> None:
    m = convergence.model_measures(**_curves(600))
    # The moving average of the 100 episodes ending at episode e is within 10% of the
    # rise from the plateau once at most 10 of them are failures: e = 600 + 90.
    assert m["converged"] == 690
    assert m["success95"] == 695  # 95 of the last 100 successes
    assert m["steps_rise"] == 650  # half of the steps' rise: 50 of the last 100 learnt
    assert m["plateau"] == pytest.approx(-130.0)


def test_earlier_learners_win_every_comparison_over_seeds() -> None:
    models = []
    for tag, switch in (("④", 400), ("⑦", 900)):
        for s in range(6):
            c = _curves(switch + 10 * s, noise=5.0, seed=s)
            models.append({"label": f"{tag} x", **convergence.model_measures(**c)})
    lo, hi = min(m["auc"] for m in models), max(m["auc"] for m in models)
    for m in models:  # auc normalised over the run, as run_measures does
        m["auc"] = (m["auc"] - lo) / (hi - lo)
    rows = convergence.comparisons(models)
    faster = {r["measure"]: r for r in rows if (r["x"], r["y"]) == ("④", "⑦")}
    for m in ("converged", "success95", "steps_rise", "auc"):
        assert faster[m]["p"] == 1.0 and faster[m]["verdict"] == "supported"
    (claim,) = [c for c in convergence.claim_verdicts(rows) if "faster than ⑦" in c["claim"]]
    assert claim["verdict"] == "supported"
    # Three seeds each that separate as cleanly give a zero-width interval: no evidence.
    few = convergence.comparisons([m for i, m in enumerate(models) if i % 6 < 3])
    assert {r["verdict"] for r in few if (r["x"], r["y"]) == ("④", "⑦")} == {"undecided at 3 seeds"}


def test_run_measures_normalise_the_area_over_the_run() -> None:
    a, b = _curves(300), _curves(1200)
    episodes = {k: np.stack([a[k], b[k]]) for k in a}
    episodes["episodes"] = np.asarray([2000, 2000])
    early, late = convergence.run_measures(episodes)
    assert 0.0 <= late["auc"] < early["auc"] <= 1.0
    assert early["converged"] < late["converged"]
