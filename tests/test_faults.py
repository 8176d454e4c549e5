"""A sweep that survives: kill and resume, bad input, numerical faults."""

import errno
import hashlib
import os
import signal
import subprocess
import sys

import flax.serialization
import jax
import numpy as np
import pytest

from jaxlc import sweep
from jaxlc.study import checkpoint
from jaxlc.study.rundir import RunDir

from .conftest import HANG_GUARD_S, SMOKE


def _tree_of_files(root):
    """``{relative path: sha256}`` of every file under ``root`` (to prove nothing changed)."""
    if not root.exists():
        return {}
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _leaves(run_dir):
    raw = flax.serialization.msgpack_restore(RunDir(run_dir).state.read_bytes())
    return jax.tree.leaves(raw["state"])


@pytest.mark.parametrize(
    "sig", [signal.SIGKILL, signal.SIGINT, signal.SIGTERM], ids=["sigkill", "ctrl-c", "sigterm"]
)
def test_interrupt_then_resume_ends_bit_for_bit_like_an_uninterrupted_run(smoke_run, tmp_path, sig):
    ref_dir, _ = smoke_run
    out = tmp_path / "killed"
    cmd = [
        sys.executable,
        "-m",
        "jaxlc.sweep",
        "--config",
        str(SMOKE),
        "--out",
        str(out),
        "--no-progress",
        "--devices",  # one CPU device, as the in-process reference run
        "1",
    ]
    # The run holds after its first full-state save until a signal comes (sweep.HOLD_ENV),
    # so the interrupt lands mid-run whatever the machine's speed: no clock, no race.
    env = {**os.environ, sweep.HOLD_ENV: "1"}
    # A job started in the background of a script (CI, `cmd &`) inherits SIGINT ignored, and
    # Python then installs no KeyboardInterrupt handler: the run would never see Ctrl-C. A
    # handler here (not an ignore) leaves the child SIGINT's default, as in a terminal.
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env
        )
    finally:
        signal.signal(signal.SIGINT, old)
    seen = []
    for line in proc.stderr:  # blocks until the run holds, or ends
        seen.append(line)
        if line.startswith(sweep.HOLD_LINE):
            break
    else:
        pytest.fail(f"the run ended without holding: {''.join(seen)[-2000:]}")
    assert RunDir(out).state.exists(), "the run held before saving its state"
    if sig != signal.SIGKILL:  # then what --resume finds can only be the save on the way out
        RunDir(out).state.unlink()
    os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=HANG_GUARD_S)
    if sig != signal.SIGKILL:  # Ctrl-C, SIGTERM: save, say how to go on, exit 128 + signal
        assert proc.returncode == 128 + sig, err[-2000:]
        assert err.strip().splitlines()[-1] == (
            f"interrupted by {sig.name}: state saved; continue with python -m jaxlc.sweep "
            f"--resume {out}"
        )
        assert RunDir(out).lock.read_bytes() == b"", "the lock's record is cleared on the way out"
    else:
        assert proc.returncode == -signal.SIGKILL
    assert not (out / "summary.json").exists(), "the kill must land before the end"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "jaxlc.sweep",
            "--resume",
            str(out),
            "--no-progress",
            "--devices",
            "1",
        ],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    # SIGKILL left the lock's record behind: the resume takes the lock over, in one line
    # naming the dead holder; after a save-and-stop there is nothing to take over.
    took_over = [line for line in done.stderr.splitlines() if "taking the lock over" in line]
    if sig == signal.SIGKILL:
        assert len(took_over) == 1 and f"pid {proc.pid} on host" in took_over[0], done.stderr
    else:
        assert not took_over, done.stderr
    ref, got = _leaves(ref_dir), _leaves(out)
    assert len(ref) == len(got)
    for a, b in zip(ref, got, strict=True):
        np.testing.assert_array_equal(a, b)
    # The same checkpoints, byte for byte.
    ref_ck = {
        k: v for k, v in _tree_of_files(ref_dir / "checkpoints").items() if k.endswith(".msgpack")
    }
    got_ck = {
        k: v for k, v in _tree_of_files(out / "checkpoints").items() if k.endswith(".msgpack")
    }
    assert ref_ck == got_ck


def _bad_cases(tmp_path, smoke_run):
    run_dir, _ = smoke_run
    ck = checkpoint.list_checkpoints(run_dir)[0]
    truncated = tmp_path / "trunc" / "ep1.msgpack"
    truncated.parent.mkdir()
    truncated.write_bytes(ck.read_bytes()[:100])
    truncated.with_suffix(".json").write_bytes(ck.with_suffix(".json").read_bytes())
    other_cfg = tmp_path / "other.toml"
    other_cfg.write_text(SMOKE.read_text().replace("episodes = 40", "episodes = 80"))
    bad_toml = tmp_path / "bad.toml"
    bad_toml.write_text("[train\nepisodes = 3\n")
    empty = tmp_path / "empty_run"
    empty.mkdir()
    s = ["--config", str(SMOKE), "--out", str(tmp_path / "new")]
    return [
        # (argv, words the one-line message must contain)
        (s + ["env.unknown=1"], "unknown config key 'env.unknown'"),
        (s + ["[nope]"], "table.key=value"),
        (s + ["bogus.k=1"], "unknown config table"),
        (s + ["train.episodes=ten"], "must be an integer"),
        (s + ["train.envs_per_model=-4"], "train.envs_per_model"),
        (s + ["ddpg.batch_size=0"], "ddpg.batch_size"),
        (s + ["grid.k=[0, 1]"], "grid.k"),
        (s + ["grid.memory=[8]"], "ddpg.batch_size"),
        (s + ["grid.memory=[]"], "at least one value"),
        (s + ["ddpg.gamma=1.5"], "ddpg.gamma"),
        (s + ["env.dt=nan"], "env.dt"),
        (s + ["train.episodes=45"], "must divide"),
        (s + ["--devices", "0"], "--devices"),
        (["--config", str(bad_toml), "--out", str(tmp_path / "new")], "not valid TOML"),
        (["--config", str(tmp_path / "missing.toml")], "does not exist"),
        (["--config", str(other_cfg), "--out", str(run_dir)], "another config"),
        (["--config", str(SMOKE), "--out", str(run_dir)], "finished run"),
        (["--resume", str(empty)], "holds no run"),
        (["--resume", str(run_dir), "train.episodes=80"], "drop --config"),
        (["--distributed", "--config", str(SMOKE)], "--distributed: pass --out"),
        (["evaluate", "--checkpoint", str(truncated)], "truncated or corrupt"),
    ]


def test_bad_input_gets_one_line_exit_2_and_touches_nothing(smoke_run, tmp_path, capsys):
    run_dir, _ = smoke_run
    cases = _bad_cases(tmp_path, smoke_run)
    assert len(cases) >= 15
    for argv, words in cases:
        before = _tree_of_files(run_dir), _tree_of_files(tmp_path)
        if argv[0] == "evaluate":
            evaluate = pytest.importorskip("jaxlc.evaluate")
            rc = evaluate.main(argv[1:])
        else:
            rc = sweep.main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2, (argv, err)
        assert len(err) == 1 and words in err[0], (argv, err)
        assert "Traceback" not in err[0]
        assert (_tree_of_files(run_dir), _tree_of_files(tmp_path)) == before, argv


@pytest.mark.slow
def test_non_finite_values_stop_the_run_naming_the_model(tmp_path, capsys):
    out = tmp_path / "overflow"
    # A reward scale this large overflows float32 on the first RL step.
    rc = sweep.main(
        [
            "--config",
            str(SMOKE),
            "--out",
            str(out),
            "--no-progress",
            "env.reward_scale=1e38",
            "grid.k=[2]",
            "grid.memory=[512]",
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 3
    assert len(err) == 1 and "model 0 (k=2, memory=512, seed 0)" in err[0], err
    assert "non-finite" in err[0] and "scan step" in err[0]
    assert not (out / "summary.json").exists()
    assert not RunDir(out).state.exists(), "a faulty state must not be saved"


def test_loading_the_training_state_as_a_checkpoint_points_to_resume(smoke_run):
    run_dir, _ = smoke_run
    with pytest.raises(checkpoint.CheckpointError) as info:
        checkpoint.load(RunDir(run_dir).state)
    msg = str(info.value)
    assert "training state, not a checkpoint" in msg and f"--resume {run_dir}" in msg
    assert "interrupted" not in msg


@pytest.mark.slow
def test_full_disk_mid_run_says_free_space_then_resume(tmp_path, capsys, monkeypatch):
    """The second full-state save meets a full disk: the process exits 2 with one line that
    says to free space and resume, and the first save is still whole and loadable."""
    out = tmp_path / "full"
    real_replace = checkpoint.os.replace
    first_state = {}

    def replace(src, dst):
        if str(dst) == str(RunDir(out).state):
            if first_state:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            first_state["bytes"] = open(src, "rb").read()
        return real_replace(src, dst)

    monkeypatch.setattr(checkpoint.os, "replace", replace)
    rc = sweep.main(["--config", str(SMOKE), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert os.strerror(errno.ENOSPC) in err[0] and "free some disk space" in err[0]
    assert f"--resume {out}" in err[0] and "save again" not in err[0]
    assert RunDir(out).state.read_bytes() == first_state["bytes"]
    assert not (out / "summary.json").exists()


def test_the_loops_fault_messages_name_the_model_and_what_to_do(tmp_path):
    """Without a sweep: a non-finite step names its model, cell, seed and scan step, and a
    failed write says to resume only once a save exists; a run ends at its episodes."""
    from jaxlc import config
    from jaxlc.learn import train
    from jaxlc.study import loop

    cfg = config.load(SMOKE, ["train.seeds=2"])
    grid = train.make_grid(cfg)
    rd = RunDir(tmp_path / "run")
    finite = np.ones((4, len(grid.seeds)), bool)
    loop._check_finite({"finite": finite}, 100, grid, rd)  # all finite: no fault
    finite[2, 3] = False
    cell = grid.cells[grid.cell_of[3]]
    with pytest.raises(loop.NumericalFault, match=r"model 3 \(k=") as fault:
        loop._check_finite({"finite": finite}, 100, grid, rd)
    assert f"seed {grid.seeds[3]}" in str(fault.value) and "scan step 102" in str(fault.value)
    assert f"memory={cell['memory']}" in str(fault.value) and "no save was made" in str(fault.value)
    err = checkpoint.WriteError(tmp_path / "x", "no space left", "free some disk space")
    assert "run the same command again" in loop.after_write_error(err, rd.root)
    rd.state.parent.mkdir(parents=True)
    rd.state.write_bytes(b"")
    assert f"--resume {rd.root}" in loop.after_write_error(err, rd.root)
    n = len(grid.seeds)
    done = {"step": np.zeros(1, int), "episodes": np.full(n, cfg.train.episodes)}
    assert loop._finished(done, cfg.train)
    assert not loop._finished({**done, "episodes": done["episodes"] - 1}, cfg.train)
    assert loop.host_devices(cfg) >= 1


def test_one_process_gathers_by_copying_and_a_bad_distributed_env_is_one_message(monkeypatch):
    """``multihost`` on one process: ``to_host`` is a host copy; ``--distributed`` with a
    process count that is not an integer is refused before JAX's runtime starts."""
    from jaxlc import config
    from jaxlc.study import multihost

    tree = {"a": jax.numpy.arange(3), "b": (jax.numpy.ones(2),)}
    host = multihost.to_host(tree)
    assert isinstance(host["a"], np.ndarray) and host["a"].tolist() == [0, 1, 2]
    monkeypatch.setenv("JAX_NUM_PROCESSES", "two")
    with pytest.raises(config.ConfigError, match="must be integers"):
        multihost.distributed_init()
