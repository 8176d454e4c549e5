"""Stop signals during a run: SIGINT, SIGTERM and SIGUSR1 each ask the run to save its full
state at the next chunk boundary and stop (``jaxlc.study.loop``); the command exits with
128 + the signal's number."""

from __future__ import annotations

import signal
import sys
import threading
import time
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils

# SIGTERM: Slurm, Kubernetes, systemd and `timeout` stopping a job; SIGUSR1: what Slurm's
# --signal sends ahead of a time limit. Each is a request to save and stop, as Ctrl-C is.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1)


class Interrupted(Exception):
    """A stop signal came; the run saved its full state and stopped at a chunk boundary."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


class StopSignals:
    """While entered, a stop signal only records itself (``signum``, the first one that came);
    the loop acts on it at the next chunk boundary, where the state and the bookkeeping
    agree. A signal ignored on entry (``nohup``, a background job's SIGINT) stays ignored;
    outside the main thread, where Python cannot catch signals, nothing is installed."""

    def __init__(self) -> None:
        self.signum = 0
        self._old: dict[int, Any] = {}

    def _record(self, signum: int, frame: Any) -> None:
        self.signum = self.signum or signum

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for s in STOP_SIGNALS:
                if signal.getsignal(s) is not signal.SIG_IGN:
                    self._old[s] = signal.signal(s, self._record)
        return self

    def __exit__(self, *exc: object) -> None:
        for s, handler in self._old.items():
            signal.signal(s, handler)


def stop_signal(stop: StopSignals) -> int:
    """The stop signal every process acts on now (0: none): any process's, so that all of
    them stop at the same chunk boundary and join the same final save."""
    if jax.process_count() == 1:
        return stop.signum
    return int(np.max(multihost_utils.process_allgather(np.asarray(stop.signum))))


# Test hook: with this variable set, a run stops after its first full-state save and waits
# for a signal, so an interrupt lands mid-run however fast or slow the machine is.
HOLD_ENV = "JAXLC_HOLD_AFTER_SAVE"
HOLD_LINE = "jaxlc: state saved; holding for a signal"


def hold_for_a_signal(stop: StopSignals) -> None:
    print(f"{HOLD_LINE} ({HOLD_ENV} is set)", file=sys.stderr, flush=True)
    # A short sleep, not signal.pause(): a signal landing between the test and the pause
    # would leave the pause waiting for a second one.
    while not stop.signum:  # a stop signal ends the wait; SIGKILL kills
        time.sleep(0.05)
