"""Statistics over seeds: interval calibration, probability of improvement, the paper's models
found by their hyperparameters, run comparison. Synthetic eval rows and fake run directories
only: no training, no JAX compile."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from jaxlc import evaluate, figures, sweep
from jaxlc.config import DDPGConfig
from jaxlc.evaluation import results, stats
from jaxlc.evaluation.numbers import read
from jaxlc.evaluation.results import OUTCOMES
from jaxlc.paper import grid as paper_grid
from jaxlc.paper.claims import CLAIM_D, COMPARISONS
from jaxlc.paper.grid import LABELS as PAPER_LABELS
from jaxlc.report import report

EPISODES = (100, 200)


def _rows(success: dict[tuple[int, int], list[float]]) -> list[results.Row]:
    """eval.json rows of a grid: ``success[(k, memory)]`` per seed at the last checkpoint
    (the first checkpoint at half of it)."""
    rows = [{"label": "scripted controller", "model": None, "seed": None, "episode": None}]
    for cell, ((k, memory), seeds) in enumerate(success.items()):
        for seed, sr in enumerate(seeds):
            model = len({r["model"] for r in rows if r["model"] is not None})
            for e in EPISODES:
                value = sr if e == EPISODES[-1] else sr / 2
                rows.append(
                    {
                        "label": f"{PAPER_LABELS[k, memory]} k={k} D={memory}",
                        "model": model,
                        "cell": cell,
                        "seed": seed,
                        "k": k,
                        "memory": memory,
                        "actor_lr": 1e-4,
                        "critic_lr": 1e-3,
                        "noise_sigma": 0.2,
                        "episode": e,
                        "success_rate": value,
                        "avg_return": -200.0 + 100.0 * value,
                    }
                )
    for r in rows:  # what the report's every-model table reads
        r.update({o: 0 for o in OUTCOMES}, cases=100, performed=70, checkpoint=None)
        r.update(dict.fromkeys(results.measures()[2:], 0.0))
        r.setdefault("success_rate", 1.0)
        r.setdefault("avg_return", -140.0)
    return [results.Row.from_dict(r) for r in rows]


def _grid(best: float, spread: float = 0.02, seeds: int = 8) -> dict:
    """Nine cells; ④ at ``best``, the rest ordered by memory (larger better) and k (smaller
    better), every cell within ``spread`` across its seeds."""
    rng = np.random.default_rng(1)
    out = {}
    for k, memory in PAPER_LABELS:
        mean = 0.5 + 0.1 * {2000: 0, 4000: 1, 8000: 2}[memory] - 0.05 * {1: 0, 2: 1, 4: 2}[k]
        if (k, memory) == (1, 4000):
            mean = best
        out[k, memory] = list(np.clip(mean + spread * rng.uniform(-1, 1, seeds), 0, 1))
    return out


def _run_dir(path: Path, rows: list) -> Path:
    (path / "eval").mkdir(parents=True)
    result = {
        "config_hash": "x",
        "cases": 100,
        "seed": 0,
        "max_steps": 1500,
        "performed": 70,
        "left": 35,
        "right": 35,
        "before_rl": {o: 0 for o in OUTCOMES},
        "traced": [0],
        "rows": [dict(r) for r in rows],
    }
    (path / "eval" / "eval.json").write_text(json.dumps(result))
    return path


def _eval_rows(run: Path) -> list[results.Row]:
    return read(run / "eval" / "eval.json", results.EvalResult).rows


def test_interval_covers_the_true_mean_95_percent_at_8_seeds() -> None:
    # Seeds' success rates: a Beta(4, 2) success probability each, seen through 70 cases;
    # one batched bootstrap per repetition (scipy resamples each row on its own).
    rng = np.random.default_rng(0)
    truth = 4 / 6
    seeds = rng.binomial(70, rng.beta(4.0, 2.0, (2000, 8))) / 70

    def mean(x: np.ndarray, axis: int = -1) -> np.ndarray:
        return np.mean(x, axis=axis)

    lo, hi = stats.interval([seeds], mean, seed=1)
    covered = (lo <= truth) & (truth <= hi)
    assert 0.90 <= covered[:200].mean() <= 0.99, covered[:200].mean()
    # 2000 repetitions tell the expanded interval (~94% here) from the plain percentile
    # interval, which covers ~88.5% at 8 seeds.
    assert 0.92 <= covered.mean() <= 0.975, covered.mean()
    d = stats.describe(seeds[0])
    assert d["mean_lo"] <= d["mean"] <= d["mean_hi"] and d["iqm_lo"] <= d["iqm"] <= d["iqm_hi"]


def test_expanded_level_widens_small_samples_only() -> None:
    assert math.isnan(stats.expanded_level(1))
    levels = [stats.expanded_level(n) for n in (2, 4, 8, 32, 1000)]
    assert levels == sorted(levels, reverse=True)
    assert levels[-1] == pytest.approx(0.95, abs=2e-3)


def test_iqm_is_the_mean_of_the_middle_half() -> None:
    assert stats.iqm(np.asarray([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 100.0])) == pytest.approx(3.5)


def test_a_dominating_cell_has_probability_of_improvement_one() -> None:
    x, y = np.linspace(0.8, 0.9, 8), np.linspace(0.1, 0.7, 8)
    assert stats.improvement([x], [y]) == (1.0, 1.0, 1.0)
    assert stats.improvement([y], [x]) == (0.0, 0.0, 0.0)
    assert stats.prob_improvement(np.ones(3), np.ones(4)) == 0.5  # ties count half
    p, lo, hi = stats.improvement([x], [np.r_[y[:7], 0.95]])
    assert p == pytest.approx(1 - 8 / 64) and lo < p <= hi  # one y above all eight x


def test_performance_profile_falls_with_tau_inside_its_band() -> None:
    share, lo, hi = stats.performance_profile([np.linspace(0.2, 0.9, 8), np.full(8, 0.5)])
    assert share[0] == 1.0 and share[-1] == 0.0
    assert np.all(np.diff(share) <= 0)
    assert np.all((lo <= share + 1e-12) & (share <= hi + 1e-12))
    assert share[stats.TAUS.searchsorted(0.5)] == pytest.approx(4 / 16)  # > tau, not >=


def test_the_paper_models_are_found_by_hyperparameters_not_labels() -> None:
    rows = _rows(_grid(best=0.9, seeds=2))
    for r in rows:  # labels that say nothing of the paper
        r.label = f"cell {r.cell}"
    cells = stats.cells_of(rows)
    tags = {paper_grid.tag_of(c.axes) for c in cells}
    assert tags == set(PAPER_LABELS.values())
    (best,) = [c for c in cells if paper_grid.is_best(c.axes)]
    assert (best.axes["k"], best.axes["memory"]) == paper_grid.BEST
    # other learning rates or noise: not one of the paper's nine, whatever its (k, memory)
    assert paper_grid.tag_of({**best.axes, "actor_lr": 3e-4}) is None
    assert paper_grid.tag_of({"k": 3, "memory": 4000}) is None
    assert paper_grid.tag_of({"k": None, "memory": None}) is None  # the scripted row
    # the sweep tags its labels by the same rule, with the paper's values as its defaults
    assert paper_grid.HYPER == {n: getattr(DDPGConfig(), n) for n in paper_grid.HYPER}
    cell = {"k": 1, "memory": 4000, **paper_grid.HYPER}
    assert sweep.model_label(cell) == "④ k=1 D=4000"
    assert sweep.model_label({**cell, "noise_sigma": 0.1}) == "k=1 D=4000 noise_sigma=0.1"
    assert sweep.model_label({**cell, "k": 3}) == "k=3 D=4000"


def test_one_seed_per_cell_runs_and_says_intervals_need_two(tmp_path: Path) -> None:
    cells = stats.cells_of(_rows(_grid(best=1.0, seeds=1)))
    assert stats.fewest_seeds(cells) == 1
    assert stats.SEEDS_NOTE in stats.seeds_note(cells)
    for row in stats.cell_table(cells):
        assert row["seeds"] == 1 and math.isfinite(row["success_mean"])
        assert math.isnan(row["success_mean_lo"]) and math.isnan(row["return_iqm_hi"])
    assert stats.performance_profile([cells[0].final_success])[0][0] == 1.0

    run = _run_dir(tmp_path / "run", _rows(_grid(best=1.0, seeds=1)))
    doc = evaluate.write_seed_stats(run / "eval", _eval_rows(run))
    assert stats.SEEDS_NOTE in doc["note"]
    text = report.build_report(run)
    assert "intervals need >= 2 seeds" in text and "| (d)" in text


def test_the_report_shows_the_ams_curve_where_the_run_has_one(tmp_path: Path) -> None:
    """``validate/ams.json`` present: the section, its figure and one table row per margin,
    each AMS value inside its interval as written; absent: no section."""
    from jaxlc.evaluation import ams, numbers

    run = _run_dir(tmp_path / "run", _rows(_grid(best=0.2, seeds=1)))
    evaluate.write_seed_stats(run / "eval", _eval_rows(run))
    assert "How close to failure" not in report.build_report(run)
    ms, ps = np.linspace(0.0, 0.5, 6), np.geomspace(1e-6, 1e-2, 6)
    curve = [ams.Point(m, p, p / 2, p * 2, p, 0.0, p * 3, 7) for m, p in zip(ms, ps, strict=True)]
    est = dict(label="④ seed 0", kind="collision", margin=0.0, cap=0.6, estimate=1e-6, lo=5e-7,
               hi=2e-6, rel_halfwidth=0.75, repeats=[1e-6, 1e-6], particles=100, kill=0.1,
               rounds=[9, 9], stopped=[True, True], distinct=[1.0, 1.0], extinct=[False, False],
               cases_started=200, trajectories=400, wall_s=1.0, matmul_peak_gflops=30)  # fmt: skip
    noisy = ams.Ams([ams.Estimate(**est, curve=curve, noise=0.3)])
    numbers.write(run / "validate" / "ams.json", noisy)
    assert numbers.read(run / "validate" / "ams.json", ams.Ams).policies[0].noise == 0.3
    assert "④ seed 0 under the training's exploration noise (sigma 0.3)" in report.build_report(run)
    older = json.loads((run / "validate" / "ams.json").read_text())  # written before the fields
    for name in ("noise", "env_steps"):
        del older["policies"][0][name]
    (tmp_path / "older.json").write_text(json.dumps(older))
    assert numbers.read(tmp_path / "older.json", ams.Ams).policies[0].noise == 0.0
    numbers.write(run / "validate" / "ams.json", ams.Ams([ams.Estimate(**est, curve=curve)]))
    lines = report.build_report(run).splitlines()
    assert not any("under the training's exploration noise" in x for x in lines)  # as it acts
    at = lines.index("## How close to failure (`python -m jaxlc.validate --method ams`)")
    end = lines.index("![The exceedance curve](validate/ams_curve.png)", at)
    table = [x.split(" | ") for x in lines[at:end] if x.startswith("| ") and x[2].isdigit()]
    assert len(table) == len(curve)
    for (m, p, lohi, *_), point in zip(table, curve, strict=True):
        lo, hi = (float(v) for v in lohi.strip("[]").split(", "))
        assert float(m[2:]) == pytest.approx(point.margin, abs=1e-3) and lo <= float(p) <= hi


def test_report_and_tables_give_the_verdicts(tmp_path: Path) -> None:
    run = _run_dir(tmp_path / "run", _rows(_grid(best=0.2)))
    rows = _eval_rows(run)
    doc = evaluate.write_seed_stats(run / "eval", rows)
    assert doc["note"] is None
    lines = (run / "eval" / "cells.csv").read_text().strip().splitlines()
    assert len(lines) == 1 + 9 * len(EPISODES)
    assert len((run / "eval" / "improvement.csv").read_text().strip().splitlines()) == 1 + 9 * 8
    # The claims have one rule each, and cells.json decides none of them (the final success
    # rates are statistics here); the report still names every claim of the README's verdict:
    # without training curves (a)-(c) wait for them, without held-out lane changes (d) is n/a.
    assert "claims" not in doc
    text = report.build_report(run)
    named = [line.split(" | ")[0][2:] for line in text.splitlines() if line.startswith("| (")]
    assert named == [c for c, _, _ in COMPARISONS] + [CLAIM_D]
    line_d = next(line for line in text.splitlines() if line.startswith("| (d)"))
    assert "**n/a**" in line_d and "needs the held-out lane changes" in line_d
    assert "(a)–(c) need the training curves" in text


def test_identical_runs_differ_by_zero(tmp_path: Path) -> None:
    rows = _rows(_grid(best=0.9))
    a, b = _run_dir(tmp_path / "a", rows), _run_dir(tmp_path / "b", rows)
    assert evaluate.main(["--compare", str(a), str(b)]) == 0
    out = b / "compare_a"
    for name in ("compare.md", "compare.csv", "compare.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    table = stats.compare(stats.cells_of(rows), stats.cells_of(rows))
    assert len(table) == 9 * len(EPISODES)
    for r in table:  # the seeds are resampled on their own in each run: an interval around 0
        assert r["diff"] == 0.0 and r["diff_lo"] < 0.0 < r["diff_hi"]


def test_a_shift_between_runs_is_found() -> None:
    a = _grid(best=0.5)
    b = {key: [v + 0.2 for v in vals] for key, vals in a.items()}
    table = stats.compare(stats.cells_of(_rows(a)), stats.cells_of(_rows(b)))
    final = [r for r in table if r["episode"] == EPISODES[-1]]
    assert all(r["diff"] == pytest.approx(0.2) and r["diff_lo"] > 0 for r in final)


@pytest.mark.slow
@pytest.mark.parametrize("change", ["cells", "episodes"])
def test_mismatched_runs_are_refused_with_exit_2(tmp_path: Path, change: str, capsys) -> None:
    rows = _rows(_grid(best=0.9, seeds=2))
    if change == "cells":
        other = [r for r in rows if r.get("memory") != 8000]
    else:  # no checkpoint episode in common
        shift = lambda e: None if e is None else e + 1  # noqa: E731 (None: the scripted row)
        other = [{**r, "episode": shift(r["episode"])} for r in rows]
    a, b = _run_dir(tmp_path / "a", rows), _run_dir(tmp_path / "b", other)
    # In this process (a subprocess per case paid ~2 s of imports); `python -m jaxlc.evaluate`
    # exits with what main returns
    assert evaluate.main(["--compare", str(a), str(b)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: the runs'"), err
    assert {"cells": "cells differ", "episodes": "none in common"}[change] in lines[0]
    assert not (b / "compare_a").exists()


def test_compare_uses_the_checkpoint_episodes_both_runs_evaluated() -> None:
    a = _grid(best=0.5)
    b = {key: [v + 0.1 for v in vals] for key, vals in a.items()}
    rows_b = [r for r in _rows(b) if r["episode"] == EPISODES[-1]]  # B: the last only
    table = stats.compare(stats.cells_of(_rows(a)), stats.cells_of(rows_b))
    assert {r["episode"] for r in table} == {EPISODES[-1]}
    assert all(r["diff"] == pytest.approx(0.1) for r in table)


def test_compare_needs_evaluated_runs(tmp_path: Path, capsys) -> None:
    a = _run_dir(tmp_path / "a", _rows(_grid(best=0.9, seeds=2)))
    assert evaluate.main(["--compare", str(a), str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "eval.json is missing" in err[0]


def test_figures_draw_bands_over_several_seeds(tmp_path: Path) -> None:
    grid = _grid(best=0.9, seeds=3)
    rows = _rows(grid)
    run = _run_dir(tmp_path / "run", rows)
    models = [r for r in rows if r["model"] is not None and r["episode"] == EPISODES[-1]]
    summary = {"models": [{k: r[k] for k in ("model", "cell", "label")} for r in models]}
    (run / "summary.json").write_text(json.dumps(summary))
    rng = np.random.default_rng(0)
    (run / "metrics").mkdir()
    np.savez(
        run / "metrics" / "episodes.npz",
        ret=rng.normal(-500, 100, (len(models), 400)),
        episodes=np.full(len(models), 400),
    )
    for name in ("traces.npz", "cases.npz"):  # fig6 reads only eval.json from these files
        np.savez(run / "eval" / name, x=np.zeros(1))
    made = [figures.fig3_returns(run), figures.fig6_checkpoints(run), figures.profiles(run)]
    assert all(p is not None and p.stat().st_size > 0 for p in made)
