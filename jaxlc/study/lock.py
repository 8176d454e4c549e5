"""One writer per run directory: an OS lock on ``RUN_DIR/lock`` for the whole life of a sweep.

The lock is ``fcntl.flock`` on a file that holds its holder's record (host, PID, start
time), so a second sweep on the directory is refused with a line that names the writer.
The kernel drops a flock when its holder dies, however it dies (SIGKILL, a crash, a
reboot), so a lock whose holder is gone never blocks anyone; the record it leaves behind
tells the next holder that the last run ended without letting go. A holder that ends
normally empties the record as it lets go.

The lock is only as good as the file system's locking: exact on a local disk; on a shared
file system it holds across hosts only where the file system passes the lock on to every
host (docs/operations.md, "One writer per run directory"). Where the file system refuses locks
altogether, ``acquire`` says so (``RunLock.locked`` is False) instead of failing the run.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Holder", "LockHeld", "RunLock", "acquire"]


@dataclass(frozen=True)
class Holder:
    """Who holds (or last held) a lock, as its record says."""

    host: str
    pid: int
    started: str  # local time with its UTC offset

    @classmethod
    def this_process(cls) -> Holder:
        return cls(socket.gethostname(), os.getpid(), time.strftime("%Y-%m-%d %H:%M:%S %z"))

    def __str__(self) -> str:
        return f"pid {self.pid} on host {self.host}, started {self.started}"

    def to_bytes(self) -> bytes:
        record = {"host": self.host, "pid": self.pid, "started": self.started}
        return (json.dumps(record) + "\n").encode()

    @classmethod
    def from_bytes(cls, data: bytes) -> Holder | None:
        """The record in ``data``; None for an empty record (no holder, or one that let go)
        or one that cannot be read (a holder killed while writing it)."""
        try:
            d = json.loads(data.decode("utf-8"))
            return cls(str(d["host"]), int(d["pid"]), str(d["started"]))
        except (ValueError, KeyError, TypeError, AttributeError):
            return None


class LockHeld(Exception):
    """Another process holds the lock; ``holder`` is its record (None: not written yet)."""

    def __init__(self, path: Path, holder: Holder | None) -> None:
        self.path, self.holder = path, holder
        # An empty record under a held lock: its holder is between taking the lock and
        # writing the record, or between clearing it and letting go.
        self.who = str(holder) if holder is not None else "another process (starting or ending)"
        super().__init__(f"{path} is locked by {self.who}")


@dataclass
class RunLock:
    """A lock taken by ``acquire``; ``release`` lets go of it."""

    path: Path
    fd: int | None
    locked: bool  # False: the file system refused the lock, nothing stops a second writer
    previous: Holder | None  # the record of a holder that ended without letting go
    reason: str = ""  # why the file system refused the lock

    def release(self) -> None:
        """Empty the record, then let go (closing the file drops the flock). Emptying first
        means a record is only ever left behind by a holder that could not run this."""
        if self.fd is None:
            return
        fd, self.fd = self.fd, None
        with contextlib.suppress(OSError):  # a failed truncation only leaves a stale record
            os.ftruncate(fd, 0)
        os.close(fd)


def _read(fd: int) -> Holder | None:
    return Holder.from_bytes(os.pread(fd, 4096, 0))


def acquire(path: Path) -> RunLock:
    """Take the lock on ``path`` (created, with its directory, if missing) without waiting,
    and write this process's record into it. Raises ``LockHeld`` while another process
    holds it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Python opens files close-on-exec: a program this process starts cannot inherit the lock.
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    reason = ""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = _read(fd)
        os.close(fd)
        raise LockHeld(path, holder) from None
    except OSError as err:  # ENOLCK, EOPNOTSUPP, ...: a file system without locks
        reason = err.strerror or str(err)
    previous = _read(fd)
    os.ftruncate(fd, 0)
    os.pwrite(fd, Holder.this_process().to_bytes(), 0)
    os.fsync(fd)
    return RunLock(path, fd, not reason, previous, reason)
