"""Learning-speed measures on hand-made training curves, and the paper's comparisons on them."""

from __future__ import annotations

import numpy as np
import pytest

from jaxlc.evaluation import convergence
from jaxlc.paper.grid import LABELS
from jaxlc.sim.reward import OUT_OF_BOUNDS, SUCCESS


def _cell(tag: str) -> dict:
    """A model of the paper's cell ``tag``, named so that the label alone would not find it:
    comparisons find the paper's models by (k, memory)."""
    (k, memory), *_ = [key for key, t in LABELS.items() if t == tag]
    return {"label": f"model k={k}", "k": k, "memory": memory}


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


def _typed(models: list[dict]) -> list[convergence.Speed]:
    return [convergence.Speed.from_dict(m) for m in models]


def test_earlier_learners_win_every_comparison_over_seeds() -> None:
    models = []
    for tag, switch in (("④", 400), ("⑦", 900)):
        for s in range(6):
            c = _curves(switch + 10 * s, noise=5.0, seed=s)
            models.append({**_cell(tag), **convergence.model_measures(**c)})
    lo, hi = min(m["auc"] for m in models), max(m["auc"] for m in models)
    for m in models:  # auc normalised over the run, as run_measures does
        m["auc"] = (m["auc"] - lo) / (hi - lo)
    rows = convergence.comparisons(_typed(models), {m: 100.0 for m in convergence.LOWER_IS_BETTER})
    faster = {r["measure"]: r for r in rows if (r["x"], r["y"]) == ("④", "⑦")}
    for m in ("converged", "success95", "steps_rise"):
        # 500 episodes earlier, on the paper's side (positive), well past the 100 margin
        assert faster[m]["p"] == 1.0 and faster[m]["verdict"] == "holds"
        assert 100 < faster[m]["diff_lo"] <= faster[m]["diff"] == pytest.approx(500, abs=5)
    (claim,) = [c for c in convergence.claim_verdicts(rows) if "faster than ⑦" in c["claim"]]
    assert claim["verdict"] == "holds"
    # Fewer than 5 seeds per cell decide nothing, however cleanly they separate.
    few = convergence.comparisons(_typed([m for i, m in enumerate(models) if i % 6 < 3]))
    assert {r["verdict"] for r in few if (r["x"], r["y"]) == ("④", "⑦")} == {"undecided at 3 seeds"}


def _seeded(switches: dict[str, list[int]]) -> list[dict]:
    return [
        {**_cell(tag), **convergence.model_measures(**_curves(sw, noise=5.0, seed=s))}
        for tag, sws in switches.items()
        for s, sw in enumerate(sws)
    ]


def _decision(models: list[dict], measure: str = "converged") -> str:
    rows = convergence.comparisons(_typed(models), {m: 100.0 for m in convergence.LOWER_IS_BETTER})
    (row,) = [r for r in rows if (r["x"], r["y"]) == ("④", "⑦") and r["measure"] == measure]
    return row["verdict"]


def test_a_difference_inside_the_margin_is_no_practical_difference() -> None:
    # ④ 10-20 episodes earlier than ⑦ at every seed: real, but inside ±100 episodes
    models = _seeded({"④": [400, 405, 410, 402, 408], "⑦": [420, 415, 425, 418, 422]})
    assert _decision(models) == "no practical difference"


def test_the_other_side_of_zero_fails_and_a_wide_interval_is_undecided() -> None:
    assert _decision(_seeded({"④": [900, 910, 905, 920, 915], "⑦": [400] * 5})) == "fails"
    # seeds of ④ spread over 1,200 episodes: the interval crosses zero and the margin
    wide = _decision(_seeded({"④": [200, 1400, 300, 1300, 800], "⑦": [700, 760, 720, 740, 730]}))
    assert wide.startswith("undecided (interval width")


def test_margins_are_two_percent_of_each_axis() -> None:
    a, b = _curves(300), _curves(1200)
    episodes = {k: np.stack([a[k], b[k]]) for k in a}
    episodes["episodes"] = np.asarray([2000, 2000])
    m = convergence.margins(episodes)
    assert m["converged"] == m["steps_rise"] == 40.0  # 2% of 2,000 episodes
    assert m["auc"] == 0.02
    assert m["plateau"] == pytest.approx(0.02 * (2000 - 130))  # the return's range
    # One order in every process (convergence.json's bytes must not follow string hashing).
    assert tuple(m) == convergence.MEASURES


def test_run_measures_normalise_the_area_over_the_run() -> None:
    a, b = _curves(300), _curves(1200)
    episodes = {k: np.stack([a[k], b[k]]) for k in a}
    episodes["episodes"] = np.asarray([2000, 2000])
    early, late = convergence.run_measures(episodes)
    assert 0.0 <= late["auc"] < early["auc"] <= 1.0
    assert early["converged"] < late["converged"]
