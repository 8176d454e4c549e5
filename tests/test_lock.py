"""One writer per run directory: a second sweep is refused while the first holds the lock, a
dead holder's lock is taken over, a file system without locks is named."""

import errno
import os
import signal
import socket
import subprocess
import sys

import pytest

from jaxlc import sweep
from jaxlc.study import lock
from jaxlc.study.rundir import RunDir

from .conftest import HANG_GUARD_S, SMOKE, wait_for_line
from .test_faults import _tree_of_files

SWEEP = [sys.executable, "-m", "jaxlc.sweep", "--no-progress"]


@pytest.mark.slow
def test_a_second_writer_is_refused_while_the_first_holds_the_lock(tmp_path):
    out = tmp_path / "run"
    first = subprocess.Popen(
        [*SWEEP, "--config", str(SMOKE), "--out", str(out), "--devices", "1"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        # holds after its first save until a signal comes: the lock is held, no clock raced
        env={**os.environ, sweep.HOLD_ENV: "1"},
    )
    try:
        wait_for_line(first, sweep.HOLD_LINE)
        before = _tree_of_files(out)
        holder = f"pid {first.pid} on host {socket.gethostname()}, started "
        launches = [
            ["--config", str(SMOKE), "--out", str(out)],  # the same launch again
            ["--config", str(SMOKE), "--out", str(out), "--force"],  # --force is no way round
            ["--resume", str(out)],
        ]
        seconds = [
            subprocess.Popen([*SWEEP, *a], stderr=subprocess.PIPE, text=True) for a in launches
        ]
        for argv, p in zip(launches, seconds, strict=True):
            _, err = p.communicate(timeout=HANG_GUARD_S)
            lines = err.strip().splitlines()
            assert p.returncode == 2, (argv, err[-2000:])
            assert len(lines) == 1, (argv, lines)
            assert lines[0].startswith(f"error: run directory '{out}' is in use by another sweep")
            assert holder in lines[0] and f"--resume {out}" in lines[0], (argv, lines)
        assert _tree_of_files(out) == before, "a refused writer touched the run directory"
        # SIGUSR1 (Slurm's warning ahead of a time limit) saves and stops like SIGTERM.
        os.kill(first.pid, signal.SIGUSR1)
        _, err = first.communicate(timeout=HANG_GUARD_S)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert first.returncode == 128 + signal.SIGUSR1, err[-2000:]
    assert err.strip().splitlines()[-1] == (
        f"interrupted by SIGUSR1: state saved; continue with python -m jaxlc.sweep --resume {out}"
    )
    # It let go on the way out: the next writer finds no holder and no stale record.
    held = lock.acquire(RunDir(out).lock)
    assert held.locked and held.previous is None
    held.release()


HOLD_LOCK = (
    "import sys; from jaxlc.study import lock; lock.acquire(sys.argv[1]); "
    "print('held', flush=True); sys.stdin.read()"
)


def test_two_processes_one_lock_and_a_dead_holder_is_taken_over(tmp_path):
    path = tmp_path / "run" / "lock"
    child = subprocess.Popen(
        [sys.executable, "-c", HOLD_LOCK, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout.readline() == "held\n"
        with pytest.raises(lock.LockHeld) as info:
            lock.acquire(path)
        assert info.value.holder.pid == child.pid
        assert info.value.holder.host == socket.gethostname()
        assert f"pid {child.pid} on host" in str(info.value)
    finally:
        child.kill()  # SIGKILL: no chance to let go or to clear its record
        child.wait()
    held = lock.acquire(path)  # the kernel dropped the dead holder's lock
    assert held.locked
    assert held.previous is not None and held.previous.pid == child.pid, "stale record unseen"
    assert lock.Holder.from_bytes(path.read_bytes()).pid == os.getpid()
    with pytest.raises(lock.LockHeld):  # one lock per file, within a process too
        lock.acquire(path)
    held.release()
    assert path.read_bytes() == b""
    again = lock.acquire(path)
    assert again.previous is None, "a clean release leaves nothing to take over"
    again.release()


def test_a_sweep_says_when_its_run_directory_cannot_be_locked(tmp_path, monkeypatch, capsys):
    def no_locks(fd, op):
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))

    monkeypatch.setattr(lock.fcntl, "flock", no_locks)
    rd = RunDir(tmp_path / "run")
    rd.lock.parent.mkdir()
    rd.lock.write_bytes(lock.Holder("elsewhere", 7, "2026-01-01 00:00:00 +0000").to_bytes())
    held = sweep.take_run_dir(rd, None, force=False, resume=True)
    try:
        assert not held.locked and held.reason == os.strerror(errno.ENOLCK)
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "cannot lock" in err[0], err
        assert "nothing stops a second sweep" in err[0] and "pid 7 on host elsewhere" in err[0]
    finally:
        held.release()
