"""Every kind of run the sweep writes evaluates to a report, or is refused in one line.

Small runs reach the code paths users meet: a model never trained past its first checkpoint,
one model of one seed, a grid that is not the paper's, a run stopped mid-chunk, and a held-out
collision record with no lag vehicle (the ego hit by its own-lane follower where the target
lane was empty); a curved road, TD3, and lateral and longitudinal control together are the runs
of tests/test_runs_evaluate_joint.py. Each is evaluated with ``python -m jaxlc.evaluate``'s
``main``; its report must hold no ``nan`` and no traceback. Every console script answers
``--help`` and refuses an unknown argument with exit status 2.
"""

from __future__ import annotations

import importlib
import json
import os
import signal
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from jaxlc import config, evaluate, figures, sweep
from jaxlc.evaluation.results import Heldout
from jaxlc.report import report_heldout
from jaxlc.study.rundir import RunDir

from .conftest import HANG_GUARD_S, SMOKE, wait_for_line

ROOT = Path(__file__).resolve().parent.parent
ARGS = ["--cases", "8", "--chunk", "4", "--lane-changes", "8", "--no-figures"]
PAPER = config.CONFIG_DIR / "paper.toml"
# configs/paper.toml at smoke size (its squared loss, its schedule: early collisions)
PAPER_SMOKE = ["ddpg.hidden=[32,32]", "ddpg.batch_size=16", "train.envs_per_model=4"]
PAPER_SMOKE += ["train.checkpoint_every=20", "env.warmup_time=10.0", "train.chunk_steps=100"]
# Each run: overrides of configs/smoke.toml (20 episodes: one checkpoint of each model).
# The runs of tests/test_runs_evaluate_joint.py (two actions, a curved road) are the others.
RUNS = {
    "paper_smoke": [*PAPER_SMOKE, "train.episodes=20", "grid.k=[1,4]", "grid.memory=[256]"],
    "one_model_untrained": ["grid.k=[1]", "grid.memory=[256]", "train.episodes=20"],
    "non_paper_grid": ["grid.k=[1,3]", "grid.memory=[256]", "train.episodes=20"],
}


def train_runs(tmp_path_factory: pytest.TempPathFactory, runs: dict) -> dict[str, Path]:
    """``{name: run directory}`` of one sweep per entry of ``runs`` (name: overrides)."""
    out = {}
    for name, overrides in runs.items():
        rd = tmp_path_factory.mktemp(name)
        base = PAPER if name.startswith("paper") else SMOKE
        sweep.run_sweep(config.load(base, overrides), rd, force=True, progress=False)
        out[name] = rd
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return train_runs(tmp_path_factory, RUNS)


def _report_is_clean(run_dir: Path) -> str:
    text = (run_dir / "report.md").read_text()
    assert "nan" not in text.replace("nanoseconds", "").lower(), text
    assert "Traceback" not in text
    return text


def _verdict_claims() -> list[str]:
    """The claims of README.md's verdict table, in order."""
    readme = (ROOT / "README.md").read_text()
    block = readme.split("<!-- publish:verdict -->")[1].split("<!-- /publish:verdict -->")[0]
    return [line.split(" | ")[0][2:] for line in block.splitlines() if line.startswith("| (")]


def check_run_evaluates(run_dir: Path, name: str, overrides: list[str], capsys) -> None:
    """``evaluate.main`` on ``run_dir`` (run ``name`` of ``overrides``) writes a clean report
    whose claims section names README.md's claims and whose rows name every cell."""
    assert evaluate.main([str(run_dir), *ARGS]) == 0, capsys.readouterr().err
    text = _report_is_clean(run_dir)
    # one section on the paper's claims, naming the claims of README.md's verdict
    assert text.count("claims") and text.count("## The paper's claims\n") == 1
    section = text.split("## The paper's claims\n")[1].split("\n## ")[0]
    named = [line.split(" | ")[0][2:] for line in section.splitlines() if line.startswith("| (")]
    assert sorted(named) == sorted(_verdict_claims())
    rows = json.loads((run_dir / "eval" / "eval.json").read_text())["rows"]
    cells = {r["label"] for r in rows if r["model"] is not None}
    base = PAPER if name.startswith("paper") else SMOKE
    assert len(cells) == len(config.load(base, overrides).grid.k)
    for label in cells:
        assert label in text


@pytest.mark.parametrize("name", list(RUNS))
def test_every_run_evaluates_to_a_report(runs, name, capsys) -> None:
    check_run_evaluates(runs[name], name, RUNS[name], capsys)


def test_a_collision_with_no_lag_vehicle_prints_dashes(runs) -> None:
    run_dir = runs["one_model_untrained"]
    if not (run_dir / "eval" / "heldout.json").is_file():
        assert evaluate.main([str(run_dir), *ARGS]) == 0
    doc_path = run_dir / "eval" / "heldout.json"
    doc = json.loads(doc_path.read_text())
    hit = {
        "label": doc["rows"][1]["label"],
        "model": 0,
        "seed": 0,
        "episode": 20,
        "case": 3,
        "partner": "own_follower",
        "yielding": False,
        "hit_speed": 4.0,
        "time_s": 2.5,
        "accept_v": 20.0,
        "accept_lead_gap": 30.0,
        "accept_lag_gap": None,  # the target lane had no lag vehicle
        "accept_lag_v": None,
    }
    doc["collisions"] = [hit, hit | {"case": 4, "accept_lag_gap": 12.0, "accept_lag_v": 18.0}]
    doc_path.write_text(json.dumps(doc))
    lines = report_heldout.collision_tally(Heldout.from_dict(doc))
    (row,) = [x for x in lines if x.startswith("| own follower")]
    # two collisions; the lag gap's median over the one that had a lag, the rest as they are
    assert row.rstrip(" |").split(" | ")[2:8] == ["2", "4.0", "2.5", "12.0", "18.0", "20.0"]
    lines = report_heldout.collision_tally(Heldout.from_dict({"collisions": [hit]}))
    (row,) = [x for x in lines if x.startswith("| own follower")]
    assert row.split(" | ")[5:7] == ["–", "–"]
    assert any("no lag vehicle" in x for x in lines)


@pytest.mark.slow
def test_a_run_stopped_mid_chunk_is_refused_in_one_line_or_evaluated(tmp_path, capsys) -> None:
    out = tmp_path / "stopped"
    cmd = [sys.executable, "-m", "jaxlc.sweep", "--config", str(SMOKE), "--out", str(out)]
    cmd += ["--no-progress", "--devices", "1", "train.episodes=20"]
    env = {**os.environ, sweep.HOLD_ENV: "1"}  # holds after its first save until a signal
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env
    )
    wait_for_line(proc, sweep.HOLD_LINE)
    os.kill(proc.pid, signal.SIGTERM)
    proc.communicate(timeout=HANG_GUARD_S)
    assert proc.returncode == 128 + signal.SIGTERM
    assert not RunDir(out).summary_json.exists()
    status = evaluate.main([str(out), *ARGS])
    err = capsys.readouterr().err.strip()
    if status == 0:
        _report_is_clean(out)
    else:
        assert status == 2 and len(err.splitlines()) == 1 and "--resume" in err, err


def _scripts() -> dict[str, str]:
    doc = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return doc["project"]["scripts"]


def _exit_status(main) -> int:
    """The exit status ``sys.exit(main())`` gives, as a console script runs it."""
    try:
        code = main()
    except SystemExit as stop:
        code = stop.code
    return 0 if code is None else code


@pytest.mark.parametrize("script", list(_scripts()))
def test_every_console_script_answers_help_and_refuses_unknown_arguments(
    script, monkeypatch, capsys
) -> None:
    """Each script's entry point with the command line in ``sys.argv``, as the installed
    script calls it (tests/test_train.py runs two of them from the venv's ``bin``)."""
    module, func = _scripts()[script].split(":")
    main = getattr(importlib.import_module(module), func)
    monkeypatch.setattr(sys, "argv", [script, "--help"])
    capsys.readouterr()
    status, out = _exit_status(main), capsys.readouterr()
    assert status == 0 and "usage:" in out.out, out.err
    monkeypatch.setattr(sys, "argv", [script, "runs/none", "--no-such-option"])
    status, err = _exit_status(main), capsys.readouterr().err
    assert status == 2 and "--no-such-option" in err, err


def test_figures_of_a_missing_run_directory_exit_2(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        figures.main([str(tmp_path / "absent")])
    assert stop.value.code == 2
    assert "is not a directory" in capsys.readouterr().err


def _suite_csv(run: Path, rates: dict[str, float]) -> None:
    """A synthetic ``eval/suite/suite.csv``: per setting the scripted controller and two
    models (one of them 2 points lower), and a setting whose commands were all declined."""
    lines = ["setting,label,model,cell,seed,lane_changes,success_rate,success_lo,success_hi"]
    for setting, rate in rates.items():
        lines.append(f"{setting},scripted,,,,1000,1.0,0.9963,1.0")
        for model, r in enumerate((rate, rate - 0.02)):
            lines.append(f"{setting},k=1,{model},0,{model},1000,{r},{r - 0.01},{min(r + 0.01, 1)}")
    lines.append("all_declined,k=1,0,0,0,0,,,")
    (run / figures.SUITE_CSV).parent.mkdir(parents=True)
    (run / figures.SUITE_CSV).write_text("\n".join(lines) + "\n")


def test_figures_draw_suites_side_by_side_and_refuse_a_run_without_one(tmp_path, capsys):
    runs = [tmp_path / "default", tmp_path / "any_road"]
    _suite_csv(runs[0], {"paper": 0.999, "harsh": 0.99})
    _suite_csv(runs[1], {"paper": 1.0, "harsh": 0.995})
    rows = figures.suite_rows(runs[0] / figures.SUITE_CSV)
    scripted, model = rows[0], rows[1]
    assert scripted["model"] is None and model["model"] == 0 and model["lane_changes"] == 1000
    assert model["success_rate"] == 0.999 and rows[-1]["success_rate"] is None
    out = tmp_path / "side_by_side.png"
    assert figures.main(["--suite", *map(str, runs), "--out", str(out)]) == 0
    assert out.stat().st_size > 0 and capsys.readouterr().out.strip() == str(out)
    absent = tmp_path / "never_evaluated"
    absent.mkdir()
    assert figures.main(["--suite", str(runs[0]), str(absent), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "never_evaluated" in err and "--suite" in err
    with pytest.raises(SystemExit) as stop:  # several runs without --suite: a usage error
        figures.main([str(runs[0]), str(runs[1])])
    assert stop.value.code == 2
