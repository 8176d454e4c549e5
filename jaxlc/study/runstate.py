"""A run's hold on its directory and what it keeps between chunks: the run directory taken
(locked, checked against the config), the host's bookkeeping, and the full training state
saved and loaded in one atomic file (``--resume``)."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import flax.serialization
import jax
import numpy as np
from jax.experimental import multihost_utils

from jaxlc import config
from jaxlc.learn import train
from jaxlc.study import checkpoint, lock
from jaxlc.study.multihost import to_host
from jaxlc.study.rundir import RunDir


def prepare_run_dir(out: Path, cfg: config.Config, force: bool) -> None:
    """Create ``out`` for ``cfg``; refuse a directory that already holds another run."""
    rd = RunDir(out)
    if rd.config.exists():
        try:
            old = rd.load_config()
        except config.ConfigError:
            old = None
        if old is None or old.hash() != cfg.hash():
            if not force:
                raise config.ConfigError(
                    f"run directory '{out}' already holds a run of another config; "
                    "choose another --out, or pass --force to overwrite it"
                )
        elif not force and rd.summary_json.exists():
            raise config.ConfigError(
                f"run directory '{out}' already holds a finished run of this config; "
                "choose another --out, or pass --force to train again"
            )
    rd.write_config(cfg)


def take_run_dir(rd: RunDir, cfg: config.Config, force: bool, resume: bool) -> lock.RunLock:
    """Lock ``rd`` for this process (one line on stderr when the last holder died holding
    it, or when the file system has no locks), then prepare it for a new run. Refuses
    (``ConfigError``) while another sweep holds it: two writers would interleave their saves."""
    try:
        held = lock.acquire(rd.lock)
    except lock.LockHeld as err:
        raise config.ConfigError(
            f"run directory '{rd.root}' is in use by another sweep ({err.who}); wait for it to "
            f"end, or stop it (SIGTERM or Ctrl-C saves) and continue with python -m "
            f"jaxlc.sweep --resume {rd.root}"
        ) from None
    if not held.locked:
        last = f"; the last record names {held.previous}" if held.previous else ""
        print(
            f"jaxlc: warning: cannot lock {rd.lock} ({held.reason}): nothing stops a second "
            f"sweep from writing to '{rd.root}'{last}",
            file=sys.stderr,
        )
    elif held.previous is not None:
        print(
            f"jaxlc: run directory '{rd.root}' was locked by {held.previous}, which is gone; "
            "taking the lock over",
            file=sys.stderr,
        )
    try:
        if not resume:
            prepare_run_dir(rd.root, cfg, force)
    except BaseException:
        held.release()
        raise
    return held


def take_everywhere(
    rd: RunDir, cfg: config.Config, force: bool, resume: bool
) -> lock.RunLock | None:
    """``take_run_dir`` on process 0, the one writer; the others learn whether it refused."""
    problem, held = "", None
    if jax.process_index() == 0:
        try:
            held = take_run_dir(rd, cfg, force, resume)
        except config.ConfigError as err:
            problem = str(err)
    if jax.process_count() > 1:
        refused = multihost_utils.broadcast_one_to_all(np.asarray(bool(problem)))
        if bool(refused) and not problem:
            problem = f"process 0 refused the run directory '{rd.root}'; see its message"
    if problem:
        raise config.ConfigError(problem)
    return held


@dataclass
class Bookkeeping:
    """What the host keeps between chunks; saved with the training state, so a resumed run
    continues its counts, its step metrics and its wall time."""

    saved: np.ndarray  # (models,) int64, episode of each model's last checkpoint written
    env_steps: int
    wall_before: float  # s of training before this process took the run over
    chunks: list[dict[str, np.ndarray]]  # step metrics, (scan steps, models) per chunk
    t0: float  # this process's clock at the start

    @classmethod
    def load(cls, host: dict[str, Any] | None, n_models: int, t0: float) -> Bookkeeping:
        if host is None:
            return cls(np.zeros(n_models, np.int64), 0, 0.0, [], t0)
        metrics = host["metrics"]
        chunks = [metrics] if metrics else []
        saved = np.array(host.get("saved", np.zeros(n_models)), np.int64)  # a writable copy
        return cls(saved, int(host["env_steps"]), float(host["wall_s"]), chunks, t0)

    def dump(self) -> dict[str, Any]:
        out = {"saved": self.saved, "env_steps": self.env_steps}
        if not self.chunks:  # nothing trained by this process: the saved record stands
            return {**out, "wall_s": self.wall_before, "metrics": {}}
        metrics = {k: np.concatenate([m[k] for m in self.chunks]) for k in self.chunks[0]}
        return {
            **out,
            "wall_s": self.wall_before + time.perf_counter() - self.t0,
            "metrics": metrics,
        }


def save_state(rd: RunDir, state: train.TrainState, host: dict[str, Any]) -> None:
    """The whole run, device state and host bookkeeping (``Bookkeeping.dump``), in one atomic
    file: a resume always sees a state and the bookkeeping that goes with it."""
    blob = flax.serialization.to_bytes({"state": to_host(state), "host": host})
    if jax.process_index() == 0:
        rd.write_bytes(rd.state, blob)


def load_state(rd: RunDir, target: train.TrainState) -> tuple[Any, dict]:
    if not rd.state.exists():
        raise config.ConfigError(
            f"no saved training state in '{rd.root}'; start a new run there "
            "with --out (and --force) instead of --resume"
        )
    empty_host = {"env_steps": 0, "wall_s": 0.0, "metrics": {}}
    try:
        raw = flax.serialization.msgpack_restore(rd.state.read_bytes())
        log = raw["state"]["log"]
        if "terms" not in log:  # saved before the log kept its reward terms by name
            log["terms"] = {n: log.pop(n) for n in ("r_s", "r_e", "r_d")}
        state = flax.serialization.from_state_dict(target, raw["state"])
    except Exception as err:  # noqa: BLE001 - any decoding failure means the same to a user
        raise checkpoint.CheckpointError(
            f"saved training state {rd.state} is truncated or corrupt ({type(err).__name__}); "
            "start the run again with --force"
        ) from None
    return state, {**empty_host, **raw["host"]}
