"""Rejax's learners train on the gymnax env through ``FiveValueAdapter`` (Rejax 0.1.3 unpacks
gymnax 0.0.x's five step values), unchanged, and learn something: a smoke run's greedy policy
beats the same learner's untrained (initial) policy on the fixed cases."""

from __future__ import annotations

import pytest

pytest.importorskip("gymnax", reason="optional: pip install -e '.[ecosystem]'")
pytest.importorskip("rejax", reason="optional: pip install -e '.[ecosystem]'")

ALGOS = ("ppo", "sac")
# Decisions of a smoke run: at this budget each learner beat its untrained policy by a wide
# margin on this project's 2-core VM in the suite's build (on the first 32 cases: return -125
# and -210 against -2004 and -1946; on 100: -130 and -205 against -2007 and -1985); at half
# of it (level 1 alone) PPO's margin was 57.
SMOKE_DECISIONS = 32_768
# Fixed cases driven: fewer than the evaluation's spill batch (``engine.SPILL_MIN_BATCH``), so
# each rollout compiles as one loop (the benchmark's 100: 25 s of the fixture's 71; 32: 11 of 56).
SMOKE_CASES = 32


@pytest.fixture(scope="module")
def rows(tmp_path_factory) -> dict[str, dict]:
    """One run of the benchmark for both learners: imports, the machine's peak and the
    fixed cases' start program are paid once."""
    csv = tmp_path_factory.mktemp("vs_rejax") / "r.csv"
    from benchmarks import vs_rejax

    out = vs_rejax.main(
        ["--algos", *ALGOS, "--seeds", "1", "--timesteps", str(SMOKE_DECISIONS)]
        + ["--cases", str(SMOKE_CASES), "--csv", str(csv)]
    )
    assert csv.is_file() and len(csv.read_text().splitlines()) == 1 + len(ALGOS)
    return {row["learner"].split()[-1]: row for row in out}


@pytest.mark.parametrize("name", ALGOS)
def test_a_rejax_learner_trains_through_the_adapter_and_beats_its_untrained_policy(name, rows):
    row = rows[name]
    assert row["decisions_per_s"] > 0 and row["decisions_per_seed"] == SMOKE_DECISIONS
    assert 0.0 <= row["success_mean"] <= 1.0
    assert row["return_mean"] > row["untrained_return"], row
