"""The sweep's chunk loop: every model of the grid trained in one process (``run_sweep``),
checkpoints and the full state saved between chunks, progress, live curves, and the run's
metrics and summary at the end (``python -m jaxlc.sweep`` is its command line)."""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils

from jaxlc import config
from jaxlc.learn import train
from jaxlc.sim.env import OBS_DIM, action_dim
from jaxlc.study import checkpoint, machine
from jaxlc.study.multihost import to_host
from jaxlc.study.rundir import RunDir
from jaxlc.study.runstate import Bookkeeping, load_state, save_state, take_everywhere
from jaxlc.study.signals import HOLD_ENV, Interrupted, StopSignals, hold_for_a_signal, stop_signal
from jaxlc.study.summary import model_meta, summarise, summary_markdown
from jaxlc.study.tracking import TensorBoard


class NumericalFault(RuntimeError):
    """A model produced a non-finite loss, reward or observation; the run stopped."""


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
        held = take_everywhere(rd, cfg, force, resume)
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
    state, host = init(train.model_keys(grid)), None
    if resume:
        state, host = load_state(rd, state)
    book = Bookkeeping.load(host, grid.size, t0)
    counters = to_host({"step": state.step, "episodes": state.episodes})
    done = int(np.minimum(counters["episodes"], t.episodes).sum())
    bar = Progress(grid.size * t.episodes, done, f"{grid.size} models", progress and lead, lead)
    metas = [model_meta(cfg, grid, i) for i in range(grid.size)]
    tracker = TensorBoard(tensorboard, metas) if tensorboard is not None and lead else None
    last_save, hold = time.perf_counter(), bool(os.environ.get(HOLD_ENV))
    chunk_env_steps = t.chunk_steps * t.envs_per_model * grid.size
    signum, first_chunk_s = 0, None
    try:
        while not _finished(counters, t):
            # Read between chunks only: there the state and the bookkeeping agree, so the
            # save below is one that a resume continues bit for bit.
            if signum := stop_signal(stop):
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
                save_state(rd, state, book.dump())
                last_save = time.perf_counter()
                if hold:
                    hold_for_a_signal(stop)
            elapsed = time.perf_counter() - t_chunk
            rate = chunk_env_steps / elapsed
            if first_chunk_s is None:  # compilation included: compile ~ this - a later chunk
                first_chunk_s = elapsed
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
        save_state(rd, state, book.dump())
        raise Interrupted(signum)
    return _finish(rd, cfg, grid, state, counters["episodes"], book, n_dev, first_chunk_s)


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
    first_chunk_s: float | None,
) -> dict[str, Any]:
    """Save the final state; write metrics and summary (process 0); return the summary.
    ``first_chunk_s``: this process's first chunk, its compilation included."""
    host = book.dump()  # once: the saved state and the summary share its wall time
    save_state(rd, state, host)
    log = {k: np.asarray(v) for k, v in to_host(state.log).columns().items()}
    lead = jax.process_index() == 0
    summary = {
        "wall_s": float(host["wall_s"]),
        "first_chunk_s": first_chunk_s,
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


def host_devices(cfg: config.Config) -> int:
    """``machine.host_devices_for`` the grid of ``cfg``, whose largest product is the DDPG
    update's (a batch through the widest layers). Plain Python: call it before JAX starts."""
    models = len(train.grid_cells(cfg)) * cfg.train.seeds
    d = cfg.ddpg
    return machine.host_devices_for(
        models, machine.largest_product(d.batch_size, (OBS_DIM, *d.hidden, action_dim(cfg.env)))
    )


def after_write_error(err: checkpoint.WriteError, out: Path | None) -> str:
    """What a user does after a failed write, once this process has exited: fix the disk,
    then resume from the last save (written atomically, so it is intact) or start again."""
    head = f"cannot write {err.path}: {err.reason}; {err.remedy}"
    if out is not None and RunDir(out).state.exists():
        return (
            f"{head}, then continue with python -m jaxlc.sweep --resume {out} "
            "(the last saved state is intact)"
        )
    return f"{head}, then run the same command again (no training state was saved yet)"
