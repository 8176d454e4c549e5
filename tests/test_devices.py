"""The models axis laid over several devices gives the results of one device."""

import os
import signal
import socket
import subprocess
import sys
import textwrap

import flax.serialization
import jax
import numpy as np

from jaxlc import sweep
from jaxlc.study import checkpoint
from jaxlc.study.rundir import RunDir

from .conftest import HANG_GUARD_S, SMOKE, wait_for_line

SCRIPT = textwrap.dedent("""
    import jax, numpy as np
    from jaxlc import config
    from jaxlc.learn import train
    cfg = config.load(config.CONFIG_DIR / "smoke.toml")
    grid = train.make_grid(cfg)  # 4 models: padded to 6 on 3 devices
    assert len(jax.devices()) == 4, jax.devices()
    results = {}
    for n in (1, 3, 4):
        init, run = train.make_grid_fns(cfg, grid, jax.devices()[:n])
        state, metrics = run(init(train.model_keys(grid)), 300)
        assert state.episodes.shape == (grid.size,) and metrics["finite"].shape[1] == grid.size
        assert int(state.learner.step.min()) > 0, "updates must have run"
        results[n] = state
    # XLA picks other kernels for other per-device batch shapes, and 300 scan steps of learning
    # amplify their rounding (the reflection-odd actor's two trunk passes more than a plain
    # actor's: up to 3e-5 on values of 1e-2 seen); a model laid on the wrong device, or given
    # another's data, would differ by the size of the values themselves.
    for n in (3, 4):
        for a, b in zip(jax.tree.leaves(results[1]), jax.tree.leaves(results[n]), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-3, atol=1e-4)
    # Evaluation lays its policies over the devices the same way (5 policies: padded to 6).
    from jaxlc.evaluation import cases
    actors = [jax.tree.map(lambda a, i=i: a[i], results[1].learner.actor) for i in range(4)]
    evals = {
        n: cases.evaluate_policies(cfg, [None, *actors], [1, 1, 1, 2, 2], cases=6,
                                      max_steps=600, traced=1, devices=n)[0]
        for n in (1, 3)
    }
    assert evals[1]["reason"].shape == (5, 6)
    np.testing.assert_array_equal(evals[1]["reason"], evals[3]["reason"])
    np.testing.assert_allclose(evals[1]["ret"], evals[3]["ret"], rtol=1e-4, atol=1e-3)
    print("devices ok")
""")


def test_grid_over_3_and_4_cpu_devices_matches_one_device():
    env = {
        **os.environ,
        # the suite's own flags kept (tests/conftest.py)
        "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=4",
        "JAX_PLATFORMS": "cpu",
    }
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT],
        env=env,
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "devices ok" in done.stdout


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _two_processes(args: list[str], extra_env: dict[str, str]) -> list[subprocess.Popen]:
    """Processes 0 and 1 of one ``--distributed`` sweep on loopback, one CPU device each."""
    port, procs = _free_port(), []
    for pid in (0, 1):
        env = {
            **os.environ,
            **extra_env,
            "JAX_PLATFORMS": "cpu",
            "JAX_COORDINATOR_ADDRESS": f"127.0.0.1:{port}",
            "JAX_NUM_PROCESSES": "2",
            "JAX_PROCESS_ID": str(pid),
        }
        cmd = [sys.executable, "-m", "jaxlc.sweep", "--no-progress", "--distributed", *args]
        procs.append(
            subprocess.Popen(
                cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
        )
    return procs


def _stop_while_held(out, procs: list[subprocess.Popen]) -> list[tuple[str, str]]:
    """Both processes hold after their first save (``sweep.HOLD_ENV``). A third sweep is
    refused, naming process 0, the lock's one holder; then each process gets a different
    signal, and both act on the same one (any process's, the larger number: SIGTERM)."""
    try:
        for p in procs:
            wait_for_line(p, sweep.HOLD_LINE)
        third = subprocess.run(
            [sys.executable, "-m", "jaxlc.sweep", "--resume", str(out), "--no-progress"],
            env={**os.environ, "JAX_PLATFORMS": "cpu"},
            capture_output=True,
            text=True,
            timeout=HANG_GUARD_S,
        )
        assert third.returncode == 2, third.stderr[-3000:]
        assert f"in use by another sweep (pid {procs[0].pid} on host" in third.stderr
        os.kill(procs[0].pid, signal.SIGUSR1)
        os.kill(procs[1].pid, signal.SIGTERM)
        return [p.communicate(timeout=HANG_GUARD_S) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


def test_two_processes_with_jax_distributed_match_one_process(tmp_path):
    """Two processes on loopback, one CPU device each, run the smoke sweep together, are
    stopped by signals after their first save, and resume: process 0 alone writes the run
    directory and holds its lock, a signal to each stops both at the same chunk boundary,
    and the params equal those of one process laying the models over two host devices.
    (That reference runs the same per-device program; a one-device program sums in
    another order, and an RL run turns such last-bit differences into different episodes
    within 40 episodes.)"""
    ref_dir, out = tmp_path / "one_host", tmp_path / "two_hosts"
    cmd = [sys.executable, "-m", "jaxlc.sweep", "--config", str(SMOKE), "--no-progress"]
    ref = subprocess.run(
        [*cmd, "--out", str(ref_dir), "--devices", "2"],
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert ref.returncode == 0, ref.stderr[-3000:]
    held = _two_processes(["--config", str(SMOKE), "--out", str(out)], {sweep.HOLD_ENV: "1"})
    stopped = _stop_while_held(out, held)
    for p, (_, err) in zip(held, stopped, strict=True):
        assert p.returncode == 128 + signal.SIGTERM, err[-3000:]
        assert err.strip().splitlines()[-1].startswith("interrupted by SIGTERM: state saved")
    assert not (out / "summary.json").exists()
    procs = _two_processes(["--resume", str(out)], {})
    outputs = [p.communicate(timeout=HANG_GUARD_S) for p in procs]
    for p, (_, err) in zip(procs, outputs, strict=True):
        assert p.returncode == 0, err[-3000:]
        assert "taking the lock over" not in err, "the stopped run let go of its lock"
    assert "Run directory" in outputs[0][0] and "Run directory" not in outputs[1][0]
    assert RunDir(out).lock.read_bytes() == b""

    def state(run_dir):
        raw = flax.serialization.msgpack_restore(RunDir(run_dir).state.read_bytes())
        return raw["state"]

    ref, got = state(ref_dir), state(out)
    np.testing.assert_array_equal(got["episodes"], ref["episodes"])
    for net in ("actor", "critic"):
        for a, b in zip(
            jax.tree.leaves(ref["learner"][net]), jax.tree.leaves(got["learner"][net]), strict=True
        ):
            np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-7)
    names = lambda d: sorted(p.relative_to(d) for p in checkpoint.list_checkpoints(d))  # noqa: E731
    assert names(out) == names(ref_dir) and names(out)
    assert (out / "summary.json").exists() and (out / "metrics" / "episodes.npz").exists()
