"""``python -m jaxlc.sweep``: train the grid of models (default: the paper's nine) in one process.

    python -m jaxlc.sweep                                  # configs/default.toml
    python -m jaxlc.sweep --config configs/smoke.toml --out runs/smoke
    python -m jaxlc.sweep train.envs_per_model=64 grid.k=[1,2] --seeds 3
    python -m jaxlc.sweep --devices 4                      # models laid over 4 devices
    python -m jaxlc.sweep --distributed ...                # one process per host (README)

The scan runs in chunks of ``train.chunk_steps``; between chunks the host saves checkpoints
(the actor of every model at episodes checkpoint_every, 2*checkpoint_every, ...), and at the
end the per-episode metrics, the loss curves, a summary table and the resolved config, all
under the run directory:

    RUN_DIR/config.toml                    resolved config (what ran)
    RUN_DIR/checkpoints/mXX_sY/epNNNNN.*   actor params (msgpack) + metadata (json)
    RUN_DIR/metrics/episodes.npz           per model: return, steps, reason, reward terms
    RUN_DIR/metrics/steps.npz              per scan step and model: losses, transitions
    RUN_DIR/summary.md, summary.json       last-100-episode success rate and return

One writer per run directory: the sweep holds an OS lock on ``RUN_DIR/lock`` for its whole
life (``jaxlc.study.lock``), and a second sweep or ``--resume`` there is refused (exit status 2).
SIGINT (Ctrl-C), SIGTERM and SIGUSR1 stop the run at the end of the chunk in flight, save
the full state and exit with 128 + the signal's number (130, 143, 138); ``--resume`` goes on.

Multi-host (``--distributed``): every process runs this same program after
``jax.distributed.initialize``; the models axis spans the devices of all processes. Process 0
alone writes, every file of the run (it has every result gathered anyway), and holds the
lock; the run directory must be on a file system that every host sees, as ``--resume`` reads
it on every process.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
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
from jaxlc.paper import grid as grid_of_paper
from jaxlc.sim.env import ACT_DIM, OBS_DIM
from jaxlc.sim.reward import REASONS, SUCCESS
from jaxlc.study import checkpoint, lock, machine
from jaxlc.study.rundir import RunDir
from jaxlc.study.summary import summary_markdown
from jaxlc.study.tracking import TensorBoard


def model_label(cell: dict[str, Any]) -> str:
    """``"④ k=1 D=4000"``-style name of a grid cell (the circled number only for the paper's
    nine, with the paper's learning rates and noise: ``paper.grid.tag_of``)."""
    base = f"k={cell['k']} D={cell['memory']}"
    tag = grid_of_paper.tag_of(cell)
    extra = [
        f"{n}={cell[n]:g}"
        for n in ("actor_lr", "critic_lr", "noise_sigma")
        if cell[n] != getattr(config.DDPGConfig(), n)
    ]
    return " ".join(([tag] if tag else []) + [base] + extra)


def model_meta(cfg: config.Config, grid: train.Grid, i: int) -> dict[str, Any]:
    cell = grid.cells[grid.cell_of[i]]
    return {
        "model": i,
        "cell": grid.cell_of[i],
        "seed": grid.seeds[i],
        "label": model_label(cell),
        **cell,
        "hidden": list(cfg.ddpg.hidden),  # the network: jaxlc.policy.load_policy
        "symmetric_actor": cfg.ddpg.symmetric_actor,
        "config_hash": cfg.hash(),
    }


def to_host(tree: Any) -> Any:
    """Numpy copy of a pytree of (possibly sharded) arrays, whole on every process."""
    if jax.process_count() == 1:
        return jax.device_get(tree)

    def whole(a: Any) -> np.ndarray:
        # host data (e.g. a state read back for --resume) is already whole on every process
        if not isinstance(a, jax.Array):
            return np.asarray(a)
        return np.asarray(multihost_utils.process_allgather(a, tiled=True))

    return jax.tree.map(whole, tree)


def distributed_init() -> None:
    """``jax.distributed.initialize`` from the usual environment: JAX_COORDINATOR_ADDRESS,
    JAX_NUM_PROCESSES and JAX_PROCESS_ID when set, else JAX's own detection (Slurm, Open
    MPI)."""
    env = os.environ
    try:
        n = int(env["JAX_NUM_PROCESSES"]) if "JAX_NUM_PROCESSES" in env else None
        pid = int(env["JAX_PROCESS_ID"]) if "JAX_PROCESS_ID" in env else None
    except ValueError:
        raise config.ConfigError(
            "--distributed: JAX_NUM_PROCESSES and JAX_PROCESS_ID must be integers"
        ) from None
    try:
        jax.distributed.initialize(num_processes=n, process_id=pid)
    except (ValueError, RuntimeError) as err:
        raise config.ConfigError(
            f"--distributed: cannot start JAX's distributed runtime ({err}); set "
            "JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES and JAX_PROCESS_ID, or run under Slurm"
        ) from None


def summarise(
    cfg: config.Config,
    grid: train.Grid,
    log: dict[str, np.ndarray],
    episodes: np.ndarray,
    last: int = 100,
) -> list[dict[str, Any]]:
    rows = []
    for i in range(grid.size):
        n = int(min(episodes[i], cfg.train.episodes))
        lo = max(0, n - last)
        reason, ret = log["reason"][i, lo:n], log["ret"][i, lo:n]
        rows.append(
            {
                **model_meta(cfg, grid, i),
                "episodes": n,
                "success_rate_last": float((reason == SUCCESS).mean()) if n else float("nan"),
                "return_last": float(ret.mean()) if n else float("nan"),
                "steps_last": float(log["steps"][i, lo:n].mean()) if n else float("nan"),
                "ends_last": {REASONS[r]: int((reason == r).sum()) for r in range(1, 5)},
            }
        )
    return rows


# --- the run directory ----------------------------------------------------------------------


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


def _take_everywhere(
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


class NumericalFault(RuntimeError):
    """A model produced a non-finite loss, reward or observation; the run stopped."""


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


def _stop_signal(stop: StopSignals) -> int:
    """The stop signal every process acts on now (0: none): any process's, so that all of
    them stop at the same chunk boundary and join the same final save."""
    if jax.process_count() == 1:
        return stop.signum
    return int(np.max(multihost_utils.process_allgather(np.asarray(stop.signum))))


# Test hook: with this variable set, a run stops after its first full-state save and waits
# for a signal, so an interrupt lands mid-run however fast or slow the machine is.
HOLD_ENV = "JAXLC_HOLD_AFTER_SAVE"
HOLD_LINE = "jaxlc: state saved; holding for a signal"


def _hold_for_a_signal(stop: StopSignals) -> None:
    print(f"{HOLD_LINE} ({HOLD_ENV} is set)", file=sys.stderr, flush=True)
    # A short sleep, not signal.pause(): a signal landing between the test and the pause
    # would leave the pause waiting for a second one.
    while not stop.signum:  # a stop signal ends the wait; SIGKILL kills
        time.sleep(0.05)


def _save_state(rd: RunDir, state: train.TrainState, host: dict[str, Any]) -> None:
    """The whole run, device state and host bookkeeping (``Bookkeeping.dump``), in one atomic
    file: a resume always sees a state and the bookkeeping that goes with it."""
    blob = flax.serialization.to_bytes({"state": to_host(state), "host": host})
    if jax.process_index() == 0:
        rd.write_bytes(rd.state, blob)


def _load_state(rd: RunDir, target: train.TrainState) -> tuple[Any, dict]:
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


# --- the training loop -----------------------------------------------------------------------


def _check_finite(metrics: dict[str, np.ndarray], step0: int, grid: train.Grid, rd: RunDir):
    """Raise ``NumericalFault`` naming the first model and scan step that went non-finite."""
    bad = np.argwhere(~np.asarray(metrics["finite"]))  # (steps, models) -> first False
    if not len(bad):
        return
    step, i = step0 + int(bad[0][0]), int(bad[0][1])
    cell = grid.cells[grid.cell_of[i]]
    kept = f"the last good save is {rd.state}" if rd.state.exists() else "no save was made yet"
    raise NumericalFault(
        f"model {i} (k={cell['k']}, memory={cell['memory']}, seed {grid.seeds[i]}) produced "
        f"a non-finite loss, reward or observation at scan step {step}; stopped without "
        f"saving it ({kept})"
    )


def _save_checkpoints(
    rd: RunDir,
    cfg: config.Config,
    grid: train.Grid,
    state: train.TrainState,
    snap_ep: np.ndarray,
    book: Bookkeeping,
) -> None:
    """Write the actor of every model that passed a checkpoint episode since the last chunk:
    the snapshot slot holds it as it was at that episode. Every process joins the gather;
    process 0, the run directory's one writer, writes."""
    new = np.nonzero(snap_ep > book.saved)[0]
    if not len(new):
        return
    actors = to_host(state.snap_actor)
    for i in new if jax.process_index() == 0 else ():
        params = jax.tree.map(lambda a, i=i: a[i], actors)
        meta = {**model_meta(cfg, grid, int(i)), "episode": int(snap_ep[i])}
        checkpoint.save(rd.checkpoint(int(i), grid.seeds[i], int(snap_ep[i])), params, meta)
    book.saved[new] = snap_ep[new]


class Progress:
    """The progress bar over every model's episodes (the models' episode range, the success
    rate of the last chunk, env-steps/s) and, on process 0, one ETA line once the pace past
    compilation is known."""

    def __init__(self, total: int, done: int, label: str, bar: bool, eta: bool) -> None:
        from tqdm import tqdm

        self.tqdm, self.total, self.done, self.eta = tqdm, total, done, eta
        self.bar = tqdm(total=total, unit="ep", disable=not bar, desc=label, dynamic_ncols=True)
        self.bar.update(done)
        self.pace: tuple[float, int] | None = None  # (clock, episodes) after the first chunk

    def update(self, per_model: np.ndarray, metrics: dict[str, np.ndarray], rate: float) -> None:
        now = int(per_model.sum())
        recent = metrics["successes"].sum() / max(1, metrics["episodes_ended"].sum())
        self.bar.set_postfix(
            per_model=f"{per_model.min()}-{per_model.max()}",
            success=f"{recent:.0%}",
            env_steps_s=f"{rate:,.0f}",
        )
        self.bar.update(now - self.done)
        self.done = now
        if self.pace is None:
            self.pace = (time.perf_counter(), now)
        elif self.eta and now - self.pace[1] >= 0.02 * (self.total - self.pace[1]):
            eta = (time.perf_counter() - self.pace[0]) / (now - self.pace[1]) * (self.total - now)
            self.tqdm.write(
                f"jaxlc: {rate:,.0f} env-steps/s; ETA {eta / 60:.1f} min at the pace so "
                "far (early episodes are the shortest)",
                file=sys.stderr,
            )
            self.eta = False

    def close(self) -> None:
        self.bar.close()


def run_sweep(
    cfg: config.Config,
    out: Path,
    force: bool = False,
    progress: bool = True,
    resume: bool = False,
    devices: int | None = None,
    tensorboard: Path | None = None,
) -> dict[str, Any]:
    """Train every model of ``cfg``'s grid and write the run directory; returns the summary.

    The run holds the run directory's lock throughout (``take_run_dir``: a second writer is
    refused). The full training state is saved atomically every ``train.save_every_s``
    seconds (at chunk boundaries), on SIGINT, SIGTERM and SIGUSR1 (then ``Interrupted`` is
    raised) and at the end; ``resume=True`` continues from it and ends with the same params,
    bit for bit, as a run never interrupted. ``tensorboard``: a directory for live curves
    (``jaxlc.study.tracking``), written at every chunk boundary."""
    n_dev = len(jax.devices()) if devices is None else devices
    train.check_devices(n_dev)
    if jax.process_count() > 1 and n_dev != len(jax.devices()):
        raise config.ConfigError("--devices: a multi-host run uses every device of every host")
    rd = RunDir(out)
    with StopSignals() as stop:  # from here on, a stop signal is a save
        held = _take_everywhere(rd, cfg, force, resume)
        try:
            return _train(cfg, rd, resume, n_dev, stop, progress, tensorboard)
        finally:
            if held is not None:
                held.release()


def _train(
    cfg: config.Config,
    rd: RunDir,
    resume: bool,
    n_dev: int,
    stop: StopSignals,
    progress: bool,
    tensorboard: Path | None,
) -> dict[str, Any]:
    """The chunk loop of ``run_sweep``, in the run directory it holds."""
    lead = jax.process_index() == 0  # writes the files of the whole run
    grid, t = train.make_grid(cfg), cfg.train
    init, run = train.make_grid_fns(cfg, grid, jax.devices()[:n_dev])
    t0 = time.perf_counter()
    state, host = init(train.model_keys(cfg, grid)), None
    if resume:
        state, host = _load_state(rd, state)
    book = Bookkeeping.load(host, grid.size, t0)
    counters = to_host({"step": state.step, "episodes": state.episodes})
    done = int(np.minimum(counters["episodes"], t.episodes).sum())
    bar = Progress(grid.size * t.episodes, done, f"{grid.size} models", progress and lead, lead)
    metas = [model_meta(cfg, grid, i) for i in range(grid.size)]
    tracker = TensorBoard(tensorboard, metas) if tensorboard is not None and lead else None
    last_save, hold = time.perf_counter(), bool(os.environ.get(HOLD_ENV))
    chunk_env_steps = t.chunk_steps * t.envs_per_model * grid.size
    signum = 0
    try:
        while not _finished(counters, t):
            # Read between chunks only: there the state and the bookkeeping agree, so the
            # save below is one that a resume continues bit for bit.
            if signum := _stop_signal(stop):
                break
            t_chunk = time.perf_counter()
            new_state, metrics = run(state, t.chunk_steps)
            metrics = to_host(metrics)
            _check_finite(metrics, int(counters["step"][0]), grid, rd)
            state = new_state
            counters = to_host(
                {"step": state.step, "episodes": state.episodes, "snap": state.snap_episode}
            )
            book.chunks.append(metrics)
            book.env_steps += chunk_env_steps
            _save_checkpoints(rd, cfg, grid, state, counters["snap"], book)
            if _save_due(last_save, t.save_every_s):
                _save_state(rd, state, book.dump())
                last_save = time.perf_counter()
                if hold:
                    _hold_for_a_signal(stop)
            rate = chunk_env_steps / (time.perf_counter() - t_chunk)
            bar.update(np.minimum(counters["episodes"], t.episodes), metrics, rate)
            if tracker is not None:  # only the log fields the curves read cross over
                log = to_host(
                    {"ret": state.log.ret, "reason": state.log.reason, "terms": state.log.terms}
                )
                steps = book.env_steps // grid.size
                tracker.chunk(steps, log, counters["episodes"], metrics, rate)
    finally:
        bar.close()
        if tracker is not None:
            tracker.close()  # flushes: the curves so far stay readable whatever stopped the run
    if signum:  # saved even before a first chunk: --resume always has a state to go on from
        _save_state(rd, state, book.dump())
        raise Interrupted(signum)
    return _finish(rd, cfg, grid, state, counters["episodes"], book, n_dev)


def _finished(counters: dict[str, np.ndarray], t: config.TrainConfig) -> bool:
    step0 = int(counters["step"][0])
    return bool((counters["episodes"] >= t.episodes).all()) or bool(
        t.max_steps and step0 >= t.max_steps
    )


def _save_due(last_save: float, every_s: float) -> bool:
    """Every process takes the same decision (process 0's clock) and joins the gather."""
    due = time.perf_counter() - last_save >= every_s
    if jax.process_count() > 1:
        due = bool(multihost_utils.broadcast_one_to_all(np.asarray(due)))
    return due


def _finish(
    rd: RunDir,
    cfg: config.Config,
    grid: train.Grid,
    state: train.TrainState,
    episodes: np.ndarray,
    book: Bookkeeping,
    n_dev: int,
) -> dict[str, Any]:
    """Save the final state; write metrics and summary (process 0); return the summary."""
    host = book.dump()  # once: the saved state and the summary share its wall time
    _save_state(rd, state, host)
    log = {k: np.asarray(v) for k, v in to_host(state.log).columns().items()}
    lead = jax.process_index() == 0
    summary = {
        "wall_s": float(host["wall_s"]),
        "env_steps": book.env_steps,
        "models": summarise(cfg, grid, log, episodes),
        "config_hash": cfg.hash(),
        "device": jax.devices()[0].device_kind,
        "devices": n_dev,
        "processes": jax.process_count(),
        # wall times travel between machines only with the machine's speed beside them
        "matmul_peak_gflops": machine.matmul_peak_gflops() if lead else float("nan"),
    }
    if jax.process_count() > 1:  # every checkpoint is on disk before the run is declared done
        multihost_utils.sync_global_devices("jaxlc.sweep: checkpoints written")
    if lead:
        rd.save_npz(rd.episodes, {**log, "episodes": episodes})
        rd.save_npz(rd.steps, host["metrics"])
        rd.write_text(rd.summary_md, summary_markdown(summary))
        rd.write_text(rd.summary_json, json.dumps(summary, indent=1))
    return summary


# --- the command line -----------------------------------------------------------------------


def host_devices(cfg: config.Config) -> int:
    """``machine.host_devices_for`` the grid of ``cfg``, whose largest product is the DDPG
    update's (a batch through the widest layers). Plain Python: call it before JAX starts."""
    models = len(train.grid_cells(cfg)) * cfg.train.seeds
    d = cfg.ddpg
    return machine.host_devices_for(
        models, machine.largest_product(d.batch_size, (OBS_DIM, *d.hidden, ACT_DIM))
    )


def _after_write_error(err: checkpoint.WriteError, out: Path | None) -> str:
    """What a user does after a failed write, once this process has exited: fix the disk,
    then resume from the last save (written atomically, so it is intact) or start again."""
    head = f"cannot write {err.path}: {err.reason}; {err.remedy}"
    if out is not None and RunDir(out).state.exists():
        return (
            f"{head}, then continue with python -m jaxlc.sweep --resume {out} "
            "(the last saved state is intact)"
        )
    return f"{head}, then run the same command again (no training state was saved yet)"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog="python -m jaxlc.sweep",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("overrides", nargs="*", help="table.key=value, e.g. train.episodes=500")
    ap.add_argument("--config", type=Path, default=None, help="TOML file (default: paper)")
    ap.add_argument("--out", type=Path, default=None, help="run directory (default: runs/...)")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per grid cell")
    ap.add_argument(
        "--resume",
        type=Path,
        default=None,
        metavar="RUN_DIR",
        help="continue the run saved in RUN_DIR",
    )
    ap.add_argument("--force", action="store_true", help="overwrite a run directory")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument(
        "--devices",
        type=int,
        default=None,
        help="devices to lay the models over (default: every GPU; on a CPU, the host-device "
        "count that trains fastest, see jaxlc/study/machine.py; XLA_FLAGS overrides it)",
    )
    ap.add_argument(
        "--distributed",
        action="store_true",
        help="multi-host: start jax.distributed from the environment (README); needs --out "
        "or --resume on a shared file system",
    )
    ap.add_argument(
        "--tensorboard",
        type=Path,
        default=None,
        metavar="DIR",
        help="write live curves per model to DIR (tensorboard --logdir DIR); needs tensorboardX",
    )
    return ap.parse_intermixed_args(argv)


def resolve_run(args: argparse.Namespace) -> tuple[config.Config, Path]:
    """The config and run directory the arguments ask for: a resumed run's own, or a new one
    (``--config`` with overrides and ``--seeds``; ``--out`` or a fresh ``runs/...``)."""
    if args.distributed and args.out is None and args.resume is None:
        raise config.ConfigError(
            "--distributed: pass --out DIR (the same on every host), or --resume DIR"
        )
    if args.resume is not None:
        if args.overrides or args.config or args.seeds is not None or args.out:
            raise config.ConfigError(
                "--resume takes the run's own config.toml; drop --config, --out, --seeds "
                "and overrides"
            )
        rd = RunDir(args.resume)
        if not rd.is_run():
            raise config.ConfigError(
                f"'{rd.root}' holds no run (no config.toml); start one with --out"
            )
        return rd.load_config(), rd.root
    overrides = list(args.overrides)
    if args.seeds is not None:
        overrides.append(f"train.seeds={args.seeds}")
    cfg = config.load(args.config, overrides)
    return cfg, args.out or Path("runs") / f"{time.strftime('%Y%m%d-%H%M%S')}-{cfg.hash()}"


def _print_done(summary: dict[str, Any], cfg: config.Config, out: Path) -> None:
    rd = RunDir(out)
    print(summary_markdown(summary))
    print(
        f"Run directory: {out}\n  config:      {rd.config}\n"
        f"  checkpoints: {rd.checkpoints}\n  metrics:     {rd.episodes.parent}\n"
        f"  summary:     {rd.summary_md}"
    )
    if checkpoint.list_checkpoints(out):
        print(f"Evaluate with: python -m jaxlc.evaluate {out}")
    else:
        print(
            f"No checkpoint was saved (the first comes at episode {cfg.train.checkpoint_every}"
            " of a model); train longer before evaluating"
        )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    out = None
    try:
        cfg, out = resolve_run(args)  # reads files only: JAX is not started yet
        if args.distributed:
            distributed_init()
        if not args.distributed:  # a multi-host run uses the hosts' devices as they are
            machine.use_host_devices(host_devices(cfg) if args.devices is None else args.devices)
        summary = run_sweep(
            cfg,
            out,
            force=args.force,
            progress=not args.no_progress,
            resume=args.resume is not None,
            devices=args.devices,
            tensorboard=args.tensorboard,
        )
    except checkpoint.WriteError as err:
        print(f"error: {_after_write_error(err, out)}", file=sys.stderr)
        return 2
    except (config.ConfigError, checkpoint.CheckpointError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except NumericalFault as err:
        print(f"error: {err}", file=sys.stderr)
        return 3
    except Interrupted as err:
        print(
            f"\ninterrupted by {err}: state saved; continue with python -m jaxlc.sweep "
            f"--resume {out}",
            file=sys.stderr,
        )
        return 128 + err.signum  # what a shell reports for a process the signal killed
    except KeyboardInterrupt:  # Ctrl-C before the run's own handler was in place
        print("\ninterrupted before training started: nothing saved", file=sys.stderr)
        return 130
    if jax.process_index() == 0:
        _print_done(summary, cfg, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
