"""The benchmark scripts run end to end in a tiny mode (so they cannot rot); no speed is
asserted, only that each measured the real work and wrote its table."""

import csv
import os
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parent.parent / "benchmarks"


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def test_sim_throughput_tiny(tmp_path):
    out = tmp_path / "sim.csv"
    cmd = [sys.executable, str(BENCH / "sim_throughput.py"), "--envs", "1", "8"]
    done = subprocess.run(
        [*cmd, "--steps", "300", "--repeats", "1", "--csv", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = _rows(out)
    assert [int(r["envs"]) for r in rows] == [1, 8]
    for r in rows:
        assert float(r["env_steps_per_s"]) > 0
        # 300 steps (30 s) after a 40 s warm-up: egos spawn, drive and some reach the RL phase
        assert 0.0 <= float(r["rl_share"]) < 1.0
    assert "best:" in done.stdout


def test_devices_throughput_tiny(tmp_path):
    out = tmp_path / "devices.csv"
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    env.pop("XLA_FLAGS", None)
    done = subprocess.run(
        [sys.executable, str(BENCH / "devices_throughput.py")]
        + ["--devices", "1", "2", "--tiny", "--csv", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = _rows(out)
    assert [int(r["devices"]) for r in rows] == [1, 2]
    for r in rows:
        assert float(r["grid_updates_per_s"]) > 0
        per_step = int(r["models"]) * int(r["envs_per_model"])  # env-steps per scan step
        expected = float(r["grid_updates_per_s"]) * per_step
        assert abs(int(r["env_steps_per_s"]) - expected) <= 1e-3 * expected
