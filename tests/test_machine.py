"""The host-device layout the CLIs pick on a CPU, and the matmul peak beside wall times."""

import os

import pytest

from jaxlc import config, evaluate, sweep
from jaxlc.study import machine

from .conftest import SMOKE

BIG = machine.largest_product(64, (14, 300, 600, 1))  # the paper's update: 64 x 300 x 600
SMALL = machine.largest_product(16, (14, 32, 32, 1))  # the smoke config's


def test_largest_product_of_the_paper_networks():
    assert BIG == 64 * 300 * 600 > machine.SMALL_PRODUCT > SMALL == 16 * 32 * 32


@pytest.mark.parametrize("cores", [1, 2, 4, 16])
@pytest.mark.parametrize("models", [1, 4, 9, 27, 72])
def test_host_devices_divide_the_models_and_stay_near_the_cores(models, cores):
    n = machine.host_devices_for(models, BIG, cores)
    assert models % n == 0, "a layout that pads would run copies of models"
    assert 1 <= n <= cores + 1
    # no larger divisor within the bound was passed over
    assert not [d for d in range(n + 1, cores + 2) if models % d == 0]
    assert machine.host_devices_for(models, SMALL, cores) == 1  # dispatch-bound: one device


def test_paper_grid_on_two_cores_gets_three_host_devices():
    assert machine.host_devices_for(9, BIG, 2) == 3  # measured fastest (docs/benchmarks.md)


def test_host_device_flag_is_left_alone_once_jax_started(monkeypatch):
    import jax

    jax.devices()  # the backends are up in this process
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_thunk_runtime=true")
    assert machine.use_host_devices(3) is False
    assert os.environ["XLA_FLAGS"] == "--xla_cpu_use_thunk_runtime=true"


@pytest.mark.parametrize(
    ("argv", "want"),
    [
        (["--config", str(SMOKE)], 1),  # small networks: one device
        (["--config", str(SMOKE), "ddpg.hidden=[300, 600]", "ddpg.batch_size=64"], None),
        (["--config", str(SMOKE), "--seeds", "3", "ddpg.hidden=[300, 600]"], None),
        (["--config", str(SMOKE), "--devices", "4"], 4),
    ],
)
def test_sweep_asks_for_the_layout_before_it_trains(monkeypatch, tmp_path, argv, want):
    asked = []
    monkeypatch.setattr(machine, "use_host_devices", asked.append)

    def stop(cfg, *args, **kwargs):
        asked.append(cfg)
        raise config.ConfigError("stopped before training")

    monkeypatch.setattr(sweep, "run_sweep", stop)
    assert sweep.main([*argv, "--out", str(tmp_path / "run")]) == 2
    n, cfg = asked
    if want is None:  # big networks: the rule for the grid's model count
        models = 4 * cfg.train.seeds
        product = machine.largest_product(cfg.ddpg.batch_size, (14, *cfg.ddpg.hidden, 1))
        want = machine.host_devices_for(models, product)
        assert product >= machine.SMALL_PRODUCT
    assert n == want


def test_evaluate_asks_for_the_layout_of_its_chunk(monkeypatch, tmp_path):
    asked = []
    monkeypatch.setattr(machine, "use_host_devices", asked.append)
    assert evaluate.main([str(tmp_path), "--chunk", "12", "--no-figures"]) == 2  # no run
    assert asked == [machine.host_devices_for(12, machine.largest_product(100, (14, 300, 600, 1)))]


def test_the_sweep_summary_names_the_machine_speed(smoke_run):
    run_dir, summary = smoke_run
    assert summary["matmul_peak_gflops"] > 0 and summary["devices"] == 1
    first = (run_dir / "summary.md").read_text().splitlines()[0]
    assert f"matmul peak of this machine {summary['matmul_peak_gflops']:.0f} GFLOP/s" in first
    assert f"({summary['env_steps'] / summary['wall_s']:,.0f}/s)" in first
    # the first chunk, its compilation included, is part of the run's wall time
    assert 0 < summary["first_chunk_s"] <= summary["wall_s"]
