"""The benchmark scripts run end to end in a tiny mode (so they cannot rot); no speed is
asserted, only that each measured the real work and wrote its table."""

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks import (
    ams_toy,
    failed_cases,
    scripted_under_noise,
    sim_throughput,
    study_summary,
    sweep_timing,
)
from benchmarks.tables import gpu

from .conftest import HANG_GUARD_S, ROOT


def _bench(name: str, args: list[str], out: Path, env: dict | None = None):
    """Run ``python -m benchmarks.NAME`` with ``args`` plus its CSV option pointing at
    ``out``; return ``(stdout, csv rows)``."""
    done = subprocess.run(
        [sys.executable, "-m", f"benchmarks.{name}", *args, "--csv", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
        env=env,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    with out.open() as f:
        return done.stdout, list(csv.DictReader(f))


def _bench_here(script, args: list[str], out: Path, capsys):
    """A benchmark module's ``main`` in this process (its imports and compiled programs
    shared with the suite), with ``args`` plus its CSV option pointing at ``out``; return
    ``(main's return, stdout, csv rows)``."""
    capsys.readouterr()
    got = script.main([*args, "--csv", str(out)])
    with out.open() as f:
        return got, capsys.readouterr().out, list(csv.DictReader(f))


@pytest.mark.slow
def test_sim_throughput_tiny(tmp_path, capsys):
    args = ["--envs", "1", "8", "--steps", "300", "--repeats", "1"]
    _, stdout, rows = _bench_here(sim_throughput, args, tmp_path / "sim.csv", capsys)
    assert [int(r["envs"]) for r in rows] == [1, 8]
    for r in rows:
        assert float(r["env_steps_per_s"]) > 0
        # 300 steps (30 s) after a 40 s warm-up: egos spawn, drive and some reach the RL phase
        assert 0.0 <= float(r["rl_share"]) < 1.0
    assert "best:" in stdout


@pytest.mark.slow
def test_devices_throughput_tiny(tmp_path):
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    # the script picks its device counts; the suite's other flags stay (tests/conftest.py)
    flags = env.get("XLA_FLAGS", "").split()
    env["XLA_FLAGS"] = " ".join(f for f in flags if "xla_force_host_platform_device_count" not in f)
    args = ["--devices", "1", "2", "--tiny"]
    _, rows = _bench("devices_throughput", args, tmp_path / "devices.csv", env)
    assert [int(r["devices"]) for r in rows] == [1, 2]
    for r in rows:
        assert float(r["grid_updates_per_s"]) > 0
        per_step = int(r["models"]) * int(r["envs_per_model"])  # env-steps per scan step
        expected = float(r["grid_updates_per_s"]) * per_step
        assert abs(int(r["env_steps_per_s"]) - expected) <= 1e-3 * expected


@pytest.mark.slow
def test_scripted_under_noise_tiny(tmp_path, capsys):
    args = ["--k", "1", "--sigma", "0", "0.2", "--envs", "16", "--steps", "700"]
    out = tmp_path / "noise.csv"
    status, _, rows = _bench_here(scripted_under_noise, args, out, capsys)
    assert status == 0
    assert [float(r["sigma"]) for r in rows] == [0.0, 0.2]
    for r in rows:
        ends = sum(int(r[c]) for c in ("success", "timeout", "out_of_bounds", "collision"))
        assert int(r["lane_changes"]) == ends > 0
    assert float(rows[0]["success_rate"]) == 1.0  # no noise: the controller never misses


@pytest.mark.slow
def test_time_to_solution_tiny(tmp_path):
    _, rows = _bench("time_to_solution", ["--tiny"], tmp_path / "tts.csv")
    (r,) = rows
    assert r["reached"] == "True" and int(r["episode"]) >= 1 and r["model"]
    per_chunk = 100 * 4 * int(r["models"])  # smoke: chunk_steps x envs_per_model x models
    assert int(r["env_steps"]) % per_chunk == 0 and int(r["env_steps"]) > 0
    assert float(r["matmul_peak_gflops"]) > 0 and float(r["wall_s"]) > 0


def test_study_summary_reads_cells_and_one_seed_studies_from_eval_csv(tmp_path, capsys):
    """Two cells x 3 seeds x checkpoints 100 and 200: cell (1, 4000) collapses from 100%
    at episode 100 to 50% at 200; seed 2 alone has a model at 100% at the end."""
    fields = ["label", "model", "seed", "k", "memory", "episode", "success_rate"]
    fields += ["duration_s", "peak_lat_acc", "overshoot_m"]
    rows = [["scripted controller", "", "", "", "", "", 1.0, 5.0, 0.5, 0.1]]
    final = {(1, 4000): [0.5, 0.5, 0.5], (2, 4000): [0.2, 0.4, 1.0]}
    for c, (k, mem) in enumerate(final):
        for s in range(3):
            for ep, rate in ((100, 1.0 if k == 1 else 0.0), (200, final[(k, mem)][s])):
                rows.append(["m", 3 * c + s, s, k, mem, ep, rate, 6.0, 1.0, 0.2])
    path = tmp_path / "eval.csv"
    with path.open("w", newline="") as f:
        csv.writer(f).writerows([fields, *rows])
    capsys.readouterr()
    study_summary.main([str(path)])
    stdout = capsys.readouterr().out
    lines = {line.split("|")[1].strip(): line for line in stdout.splitlines() if "| " in line}
    collapsed = [c.strip() for c in lines["④ k=1 D=4000"].split("|")]
    assert collapsed[3].startswith("50.0%") and collapsed[4] == "100.0% (100)"
    assert collapsed[5] == "50.0%"  # the drop from the best checkpoint to the last
    assert "Read as 3 one-seed studies: 1 of 3 have a model at >= 99%" in stdout


def test_failed_cases_lists_each_failed_lane_change_of_each_policy(tmp_path):
    """Two policies on four drawn cases (one case with no lane change): only out of bounds,
    collision and timeout are rows, under their policy's label, with where the ego ended."""
    from jaxlc.sim.reward import COLLISION, NO_GAP, OUT_OF_BOUNDS, SUCCESS, TIMEOUT

    reason = np.array(
        [[SUCCESS, OUT_OF_BOUNDS, NO_GAP, SUCCESS], [TIMEOUT, SUCCESS, NO_GAP, COLLISION]]
    )
    np.savez(
        tmp_path / "heldout_cases.npz",
        reason=reason,
        performed=np.array([True, True, False, True]),
        case=np.array([10, 11, 12, 13]),
        side=np.array([1, -1, 1, -1]),
        steps=np.array([[40, 1, 0, 45], [100, 41, 0, 30]]),
        final_offset=np.array([[0.1, 3.7, 0.0, 0.0], [0.4, 0.0, 0.0, 1.5]]),
        final_psi=np.zeros((2, 4)),
        final_omega=np.zeros((2, 4)),
    )
    (tmp_path / "heldout.csv").write_text("label,seed\nscripted controller,\nmodel,0\n")
    rows = failed_cases.main([str(tmp_path)])
    got = [(r["label"], r["case"], r["reason"], r["rl_steps"], r["final_offset_m"]) for r in rows]
    assert got == [
        ("scripted controller", 11, "out_of_bounds", 1, 3.7),
        ("model", 10, "timeout", 100, 0.4),
        ("model", 13, "collision", 30, 1.5),
    ]
    assert (tmp_path / "failed_cases.csv").read_text().count("\n") == 4  # header + 3 rows


def test_sweep_timing_keeps_the_timing_and_counts_the_models(smoke_run, smoke_cfg, tmp_path):
    """The light summary a GPU benchmark commits: the run's timing and size without its
    per-model rows, and a steady rate after the first chunk that counts the env-steps the
    first chunk did not (``tables/gpu.sweep_steady``)."""
    run_dir, summary = smoke_run
    out = tmp_path / "sweep.json"
    sweep_timing.main(run_dir, out)
    light = json.loads(out.read_text())
    assert light["models"] == len(summary["models"]) and "config" not in light
    assert light["wall_s"] == summary["wall_s"] and light["env_steps"] == summary["env_steps"]
    t = smoke_cfg.train
    assert (light["episodes_per_model"], light["envs_per_model"]) == (t.episodes, t.envs_per_model)
    first = t.chunk_steps * t.envs_per_model * light["models"]
    assert 0 < first < light["env_steps"]
    expected = (light["env_steps"] - first) / (light["wall_s"] - light["first_chunk_s"])
    assert gpu.sweep_steady(light) == pytest.approx(expected)


def test_program_hashes_tell_the_traffics_apart_and_repeat():
    """The programs' hashes that show two commits run the same simulator: one per traffic and
    program, the same on a second lowering, different between the traffics."""
    first = sim_throughput.hashes(envs=2)
    assert sorted(first) == ["hazards reset", "hazards step", "paper reset", "paper step"]
    assert sim_throughput.hashes(envs=2) == first
    assert first["paper step"] != first["hazards step"]
    assert len(set(first.values())) == 4


COMMANDS = sorted(p.stem for p in (ROOT / "benchmarks").glob("*.py") if p.stem != "__init__")
# Every script's ``--help`` run as ``python -m`` runs it (``runpy``), in one interpreter: a
# subprocess per script paid ~1.3 s of imports apiece. Prints ``{name: [exit code, stdout]}``.
HELP = """
import contextlib, io, json, runpy, sys
out = {}
for name in sys.argv[1:]:
    sys.argv, buf = [name, "--help"], io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            runpy.run_module(f"benchmarks.{name}", run_name="__main__", alter_sys=True)
        code = "returned without exiting"
    except SystemExit as e:
        code = e.code
    except Exception as e:  # noqa: BLE001  (reported per script, not as one failure)
        code = repr(e)
    out[name] = [code, buf.getvalue()]
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def helps() -> dict[str, list]:
    done = subprocess.run(
        [sys.executable, "-c", HELP, *COMMANDS],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.splitlines()[-1])


@pytest.mark.slow
@pytest.mark.parametrize("name", COMMANDS)
def test_every_script_is_a_command_with_help(name, helps):
    """``python -m benchmarks.NAME --help`` from the repository root, as the docs run them."""
    code, text = helps[name]
    assert code == 0 and text.startswith("usage:"), (code, text[-2000:])


def test_ams_toy_tiny(tmp_path, capsys):
    """Three intervals of two AMS runs on a 20-step walk: a row per interval (Cox's, above
    0), every run's estimate kept, the coverage counted from the rows."""
    args = ["--repeats", "3", "--runs", "2", "--particles", "16", "--steps", "20"]
    summary = ams_toy.main([*args, "--level", "10", "--out", str(tmp_path)])
    with (tmp_path / "repeats.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 and summary["truth"] == ams_toy.truth(20, 10)
    for r in rows:
        assert 0 < float(r["lo"]) <= float(r["hi"])
        covers = float(r["lo"]) <= summary["truth"] <= float(r["hi"])
        assert int(r["covers"]) == covers
    assert summary["covered"] == sum(int(r["covers"]) for r in rows)
    assert json.loads((tmp_path / "summary.json").read_text())["repeats"] == 3
    assert np.load(tmp_path / "estimates.npy").shape == (3, 2)
    assert "covered:" in capsys.readouterr().out
