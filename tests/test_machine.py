"""The host-device layout the CLIs pick on a CPU, and the matmul peak beside wall times."""

import os

import pytest

from jaxlc import config, evaluate, machine, sweep

from .conftest import SMOKE


@pytest.mark.parametrize("cores", [1, 2, 4, 16])
@pytest.mark.parametrize("models", [1, 4, 9, 27, 72])
def test_host_devices_divide_the_models_and_stay_near_the_cores(models, cores):
    n = machine.host_devices_for(models, cores)
    assert models % n == 0, "a layout that pads would run copies of models"
    assert 1 <= n <= cores + 1
    # no larger divisor within the bound was passed over
    assert not [d for d in range(n + 1, cores + 2) if models % d == 0]


def test_paper_grid_on_two_cores_gets_three_host_devices():
    assert machine.host_devices_for(9, 2) == 3  # measured fastest (README, "Devices")


def test_host_device_flag_is_left_alone_once_jax_started(monkeypatch):
    import jax

    jax.devices()  # the backends are up in this process
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_thunk_runtime=true")
    assert machine.use_host_devices(3) is False
    assert os.environ["XLA_FLAGS"] == "--xla_cpu_use_thunk_runtime=true"


@pytest.mark.parametrize(
    ("argv", "want"),
    [
        (["--config", str(SMOKE)], machine.host_devices_for(4)),  # smoke: 2 x 2 cells
        (["--config", str(SMOKE), "--seeds", "3"], machine.host_devices_for(12)),
        (["--config", str(SMOKE), "--devices", "4"], 4),
    ],
)
def test_sweep_asks_for_the_layout_before_it_trains(monkeypatch, tmp_path, argv, want):
    asked = []
    monkeypatch.setattr(machine, "use_host_devices", asked.append)

    def stop(*args, **kwargs):
        raise config.ConfigError("stopped before training")

    monkeypatch.setattr(sweep, "run_sweep", stop)
    assert sweep.main([*argv, "--out", str(tmp_path / "run")]) == 2
    assert asked == [want]


def test_evaluate_asks_for_the_layout_of_its_chunk(monkeypatch, tmp_path):
    asked = []
    monkeypatch.setattr(machine, "use_host_devices", asked.append)
    assert evaluate.main([str(tmp_path), "--chunk", "12", "--no-figures"]) == 2  # no run
    assert asked == [machine.host_devices_for(12)]
