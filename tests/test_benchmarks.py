"""The benchmark scripts run end to end in a tiny mode (so they cannot rot); no speed is
asserted, only that each measured the real work and wrote its table."""

import csv
import os
import subprocess
import sys
from pathlib import Path

from .conftest import HANG_GUARD_S

BENCH = Path(__file__).resolve().parent.parent / "benchmarks"


def _bench(script: str, args: list[str], out: Path, env: dict | None = None):
    """Run ``benchmarks/script`` with ``args`` plus its CSV option pointing at ``out``;
    return ``(stdout, csv rows)``."""
    done = subprocess.run(
        [sys.executable, str(BENCH / script), *args, "--csv", str(out)],
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
        env=env,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    with out.open() as f:
        return done.stdout, list(csv.DictReader(f))


def test_sim_throughput_tiny(tmp_path):
    args = ["--envs", "1", "8", "--steps", "300", "--repeats", "1"]
    stdout, rows = _bench("sim_throughput.py", args, tmp_path / "sim.csv")
    assert [int(r["envs"]) for r in rows] == [1, 8]
    for r in rows:
        assert float(r["env_steps_per_s"]) > 0
        # 300 steps (30 s) after a 40 s warm-up: egos spawn, drive and some reach the RL phase
        assert 0.0 <= float(r["rl_share"]) < 1.0
    assert "best:" in stdout


def test_devices_throughput_tiny(tmp_path):
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    env.pop("XLA_FLAGS", None)
    args = ["--devices", "1", "2", "--tiny"]
    _, rows = _bench("devices_throughput.py", args, tmp_path / "devices.csv", env)
    assert [int(r["devices"]) for r in rows] == [1, 2]
    for r in rows:
        assert float(r["grid_updates_per_s"]) > 0
        per_step = int(r["models"]) * int(r["envs_per_model"])  # env-steps per scan step
        expected = float(r["grid_updates_per_s"]) * per_step
        assert abs(int(r["env_steps_per_s"]) - expected) <= 1e-3 * expected


def test_scripted_under_noise_tiny(tmp_path):
    args = ["--k", "1", "--sigma", "0", "0.2", "--envs", "16", "--steps", "700"]
    _, rows = _bench("scripted_under_noise.py", args, tmp_path / "noise.csv")
    assert [float(r["sigma"]) for r in rows] == [0.0, 0.2]
    for r in rows:
        ends = sum(int(r[c]) for c in ("success", "timeout", "out_of_bounds", "collision"))
        assert int(r["lane_changes"]) == ends > 0
    assert float(rows[0]["success_rate"]) == 1.0  # no noise: the controller never misses


def test_time_to_solution_tiny(tmp_path):
    _, rows = _bench("time_to_solution.py", ["--tiny"], tmp_path / "tts.csv")
    (r,) = rows
    assert r["reached"] == "True" and int(r["episode"]) >= 1 and r["model"]
    per_chunk = 100 * 4 * int(r["models"])  # smoke: chunk_steps x envs_per_model x models
    assert int(r["env_steps"]) % per_chunk == 0 and int(r["env_steps"]) > 0
    assert float(r["matmul_peak_gflops"]) > 0 and float(r["wall_s"]) > 0
