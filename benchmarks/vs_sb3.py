"""Stable-Baselines3 DDPG (PyTorch, CPU) against jaxlc's trainer, on the jaxlc lane-change task.

Both sides use the config's settings (the paper's; README, "Decisions beyond the paper"):
actor and critic MLPs 300-600 with ReLU (tanh actor output), actor lr 1e-4, critic lr 1e-3,
batch 64, gamma 0.98, the config's tau, Gaussian exploration noise sigma 0.2, replay memory
4000, action-update step k = 1, updates from the first full batch on. jaxlc's Huber critic
loss and mirrored batches have no SB3 counterpart: ``ddpg.huber_delta=0 ddpg.mirror=false``
makes the two learners the same algorithm.

SB3: ``DDPG`` on ``jaxlc.gym.LaneChangeGymEnv`` (one gym step = one RL decision; the wrapper
runs the rest of the traffic simulation inside one jitted call), ``train_freq=1``,
``gradient_steps=1``: one update per transition. SB3 has a single ``learning_rate``, and
``TD3.train`` writes it into BOTH optimisers before every update (``_update_learning_rate``),
so setting the critic optimiser's param group once would be undone at the first update;
``PaperDDPG`` overrides that hook so the actor gets ``learning_rate`` and the critic
``critic_learning_rate`` (checked after the run). What still differs from jaxlc: SB3's last
layers keep PyTorch's default init (not U(+-3e-3)), its noise is an untruncated normal
(jaxlc truncates at 2 sigma), and Monitor/DummyVecEnv add their own per-step overhead.

jaxlc: ``train.make_grid_fns`` with a one-cell grid (grid.k=[1], grid.memory=[4000]): one
model whose ``train.envs_per_model`` envs (32) step in parallel with one update per scan step,
so it gathers several transitions per update (the ratio is printed).

Each single-model run stops when the success rate over the last ``--window`` episodes first
reaches ``--target``, or after ``--max-minutes`` or ``--max-episodes``. Reported: updates/s,
env transitions/s (RL decisions), the wall time to the target (jaxlc: from the episode log,
at the end of the chunk holding that episode), or "not reached in X min at Y episodes". Every
wall time starts after compilation, which is shown apart: jaxlc's init plus the ahead-of-time
compile of its chunk program; for SB3, the wrapper's first reset and step.

Nine models: jaxlc's grid (k x memory of the config, nine models for configs/paper.toml)
trained side by side until every model has ``--nine-episodes`` episodes, against nine SB3
runs one after another, EXTRAPOLATED as 9 x the wall time the measured SB3 run took to its
``--nine-episodes``-th episode (lowered to the episodes SB3 finished, if fewer).

    python -m benchmarks.vs_sb3                       # up to ~25 min (SB3 capped at 20)
    python -m benchmarks.vs_sb3 --tiny                # tiny nets and runs, for tests

Writes ``benchmarks/results/vs_sb3.csv``.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from collections.abc import Callable
from datetime import date
from pathlib import Path
from typing import Any

import jax
import numpy as np

from benchmarks.csvfile import write_csv
from jaxlc import config
from jaxlc.learn import train
from jaxlc.sim.reward import REASONS, SUCCESS

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "benchmarks" / "results"
TINY_OVERRIDES = [
    "ddpg.hidden=[16, 16]",
    "ddpg.batch_size=16",
    "train.envs_per_model=4",
    "train.chunk_steps=25",
    "env.warmup_time=5.0",
]


def _load() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


def _with_load(fn: Callable[..., dict[str, Any]], *args: Any, **kwargs: Any) -> dict[str, Any]:
    """``fn``'s result plus the 1-minute load average before and after (a shared machine)."""
    before = os.getloadavg()[0]
    row = fn(*args, **kwargs)
    row["load_before"], row["load_after"] = before, os.getloadavg()[0]
    return row


def first_reached(success: np.ndarray, target: float, window: int) -> int | None:
    """Index of the first episode at which the success rate over the last ``window`` episodes
    (that one included) is at least ``target``; None if never."""
    if len(success) < window:
        return None
    c = np.concatenate([[0], np.cumsum(success, dtype=np.int64)])
    rate = (c[window:] - c[:-window]) / window
    hit = np.nonzero(rate >= target - 1e-9)[0]
    return int(hit[0]) + window - 1 if len(hit) else None


def run_sb3(
    cfg: config.Config,
    *,
    memory: int,
    seed: int,
    target: float,
    window: int,
    max_seconds: float,
    max_episodes: int,
) -> dict[str, Any]:
    """One SB3 DDPG run with the paper's settings on the gym wrapper; see the module doc."""
    import torch
    from stable_baselines3 import DDPG
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.noise import NormalActionNoise
    from stable_baselines3.common.utils import update_learning_rate

    from jaxlc.gym import LaneChangeGymEnv

    d = cfg.ddpg

    class PaperDDPG(DDPG):
        """DDPG with separate actor and critic learning rates, and its update time summed."""

        def __init__(self, *args: Any, critic_learning_rate: float, **kwargs: Any) -> None:
            self.critic_learning_rate = critic_learning_rate
            self.train_seconds = 0.0
            super().__init__(*args, **kwargs)

        def _update_learning_rate(self, optimizers: Any) -> None:
            actor_opt, critic_opt = optimizers  # TD3.train passes [actor's, critic's]
            update_learning_rate(actor_opt, self.lr_schedule(self._current_progress_remaining))
            update_learning_rate(critic_opt, self.critic_learning_rate)

        def train(self, gradient_steps: int, batch_size: int = 100) -> None:
            t = time.perf_counter()
            super().train(gradient_steps, batch_size)
            self.train_seconds += time.perf_counter() - t

    times: list[float] = []
    reasons: list[int] = []
    state = {"reached_at": None}

    class Tracker(BaseCallback):
        """Logs each episode's end time and reason; stops at the target, time or episodes."""

        def _on_step(self) -> bool:
            now = time.perf_counter() - t0
            for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
                if done:
                    times.append(now)
                    reasons.append(REASONS.index(info["reason"]))
                    last = np.asarray(reasons[-window:]) == SUCCESS
                    if len(last) == window and last.mean() >= target - 1e-9:
                        state["reached_at"] = len(reasons) - 1
            done = state["reached_at"] is not None or len(reasons) >= max_episodes
            return not (done or now >= max_seconds)

    env = LaneChangeGymEnv(cfg, k=1)
    # Compile the wrapper outside the timing, as jaxlc's trainer is (both are shown apart).
    t_compile = time.perf_counter()
    env.reset(seed=seed)
    env.step(np.zeros(1, np.float32))
    compile_s = time.perf_counter() - t_compile
    model = PaperDDPG(
        "MlpPolicy",
        env,
        learning_rate=d.actor_lr,
        critic_learning_rate=d.critic_lr,
        buffer_size=memory,
        learning_starts=d.batch_size,
        batch_size=d.batch_size,
        tau=d.tau,
        gamma=d.gamma,
        train_freq=1,
        gradient_steps=1,
        action_noise=NormalActionNoise(np.zeros(1), np.full(1, d.noise_sigma)),
        policy_kwargs={"net_arch": {"pi": list(d.hidden), "qf": list(d.hidden)}},
        seed=seed,
        device="cpu",
        verbose=0,
    )
    update_learning_rate(model.critic.optimizer, d.critic_lr)  # right for the first update too
    t0 = time.perf_counter()
    model.learn(total_timesteps=10**10, callback=Tracker())
    wall = time.perf_counter() - t0
    lrs = tuple(m.optimizer.param_groups[0]["lr"] for m in (model.actor, model.critic))
    if not np.allclose(lrs, (d.actor_lr, d.critic_lr)):
        raise RuntimeError(f"SB3 learning rates are {lrs}, expected {(d.actor_lr, d.critic_lr)}")
    success = np.asarray(reasons) == SUCCESS
    hit = state["reached_at"]
    return {
        "system": f"SB3 {__import__('stable_baselines3').__version__} DDPG, torch "
        f"{torch.__version__} ({torch.get_num_threads()} threads)",
        "models": 1,
        "episodes": len(reasons),
        "wall_s": wall,
        "updates": int(model._n_updates),
        "updates_per_s": model._n_updates / wall,
        "update_only_per_s": model._n_updates / max(model.train_seconds, 1e-9),
        "transitions": int(model.num_timesteps),
        "transitions_per_s": model.num_timesteps / wall,
        "env_steps_per_s": float("nan"),
        "compile_s": compile_s,
        "time_to_target_s": times[hit] if hit is not None else float("nan"),
        "episode_of_target": hit + 1 if hit is not None else float("nan"),
        "success_last_window": float(success[-window:].mean()) if len(success) else float("nan"),
        "episode_times": np.asarray(times),
        "lrs": lrs,
    }


def _train_until(
    cfg: config.Config, stop: Callable[[Any, float], bool], max_seconds: float
) -> dict[str, Any]:
    """Run jaxlc's trainer for ``cfg``'s grid chunk by chunk until ``stop(state, elapsed)`` or
    ``max_seconds``; returns the state, the chunk end times and the summed metrics."""
    grid = train.make_grid(cfg)
    init, run = train.make_grid_fns(cfg, grid)
    t0 = time.perf_counter()
    state = jax.block_until_ready(init(train.model_keys(grid)))
    # Compiled ahead, so that the timed loop below holds no compilation (timed apart).
    run_chunk = run.lower(state, cfg.train.chunk_steps).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    chunk_end: list[float] = []
    updates = transitions = 0
    while True:
        state, m = run_chunk(state)
        m = jax.device_get(m)
        chunk_end.append(time.perf_counter() - t0)
        updates += int(np.isfinite(m["critic_loss"]).sum())
        transitions += int(m["transitions"].sum())
        if stop(state, chunk_end[-1]) or chunk_end[-1] >= max_seconds:
            break
    steps = len(chunk_end) * cfg.train.chunk_steps
    return {
        "state": state,
        "grid": grid,
        "chunk_end": np.asarray(chunk_end),
        "wall_s": chunk_end[-1],
        "compile_s": compile_s,
        "updates": updates,
        "transitions": transitions,
        "env_steps": steps * cfg.train.envs_per_model * grid.size,
    }


def _with_episode_cap(overrides: list[str], episodes: int, cfg_path: Path | None) -> config.Config:
    """``cfg`` whose episode log holds ``episodes`` (checkpoint_every must divide it)."""
    base = config.load(cfg_path, overrides)
    every = base.train.checkpoint_every
    cap = max(every, math.ceil(episodes / every) * every)
    return config.load(cfg_path, [*overrides, f"train.episodes={cap}"])


def run_jaxlc_one(
    cfg_path: Path | None,
    overrides: list[str],
    *,
    memory: int,
    target: float,
    window: int,
    max_seconds: float,
    max_episodes: int,
) -> dict[str, Any]:
    """One jaxlc model (one-cell grid, k = 1) run the same way as ``run_sb3``."""
    cfg = _with_episode_cap(
        [*overrides, "grid.k=[1]", f"grid.memory=[{memory}]"], max_episodes, cfg_path
    )

    def reasons(state: Any) -> np.ndarray:
        n = int(state.episodes[0])
        return np.asarray(jax.device_get(state.log.reason[0, :n]))

    def stop(state: Any, elapsed: float) -> bool:
        r = reasons(state)
        return len(r) >= max_episodes or first_reached(r == SUCCESS, target, window) is not None

    out = _train_until(cfg, stop, max_seconds)
    state = out["state"]
    success = reasons(state) == SUCCESS
    hit = first_reached(success, target, window)
    t_hit = float("nan")
    if hit is not None:
        at_step = int(jax.device_get(state.log.at_step[0, hit]))
        t_hit = float(out["chunk_end"][at_step // cfg.train.chunk_steps])
    return {
        "system": f"jaxlc {jax.__version__} trainer, {cfg.train.envs_per_model} envs/model",
        "models": 1,
        "episodes": len(success),
        **_throughput(out),
        "time_to_target_s": t_hit,
        "episode_of_target": hit + 1 if hit is not None else float("nan"),
        "success_last_window": float(success[-window:].mean()) if len(success) else float("nan"),
    }


def _throughput(out: dict[str, Any]) -> dict[str, Any]:
    """The rate columns of a jaxlc row, from what ``_train_until`` measured."""
    wall = out["wall_s"]
    return {
        "wall_s": wall,
        "updates": out["updates"],
        "updates_per_s": out["updates"] / wall,
        "update_only_per_s": float("nan"),
        "transitions": out["transitions"],
        "transitions_per_s": out["transitions"] / wall,
        "env_steps_per_s": out["env_steps"] / wall,
        "compile_s": out["compile_s"],
    }


def run_jaxlc_grid(
    cfg_path: Path | None, overrides: list[str], *, episodes: int, max_seconds: float
) -> dict[str, Any]:
    """The config's whole grid, side by side, until every model has ``episodes`` episodes."""
    cfg = _with_episode_cap(overrides, episodes, cfg_path)
    out = _train_until(
        cfg, lambda state, _: bool(np.min(np.asarray(state.episodes)) >= episodes), max_seconds
    )
    done = np.minimum(np.asarray(out["state"].episodes), cfg.train.episodes)
    return {
        "system": f"jaxlc {jax.__version__} grid, {cfg.train.envs_per_model} envs/model",
        "models": out["grid"].size,
        "episodes": int(done.min()),
        **_throughput(out),
        "time_to_target_s": float("nan"),
        "episode_of_target": float("nan"),
        "success_last_window": float("nan"),
    }


def _fmt_target(r: dict[str, Any]) -> str:
    if math.isfinite(r["time_to_target_s"]):
        return f"{r['time_to_target_s']:.0f} s (ep {r['episode_of_target']:,})"
    return f"not reached in {r['wall_s'] / 60:.1f} min at {r['episodes']:,} episodes"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--config", type=Path, default=None, help="TOML (default: paper)")
    ap.add_argument("--target", type=float, default=0.9, help="success rate to reach")
    ap.add_argument("--window", type=int, default=100, help="episodes the rate is taken over")
    ap.add_argument("--max-minutes", type=float, default=20.0, help="per single-model run")
    ap.add_argument("--max-episodes", type=int, default=10_000, help="per single-model run")
    ap.add_argument("--memory", type=int, default=4000, help="replay memory of the single runs")
    ap.add_argument("--nine-episodes", type=int, default=500, help="episodes per model")
    ap.add_argument("--nine-max-minutes", type=float, default=8.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--csv", type=Path, default=RESULTS / "vs_sb3.csv")
    ap.add_argument("--tiny", action="store_true", help="tiny nets and runs, for tests")
    ap.add_argument("overrides", nargs="*", help="config overrides, table.key=value")
    args = ap.parse_args(argv)
    overrides = list(args.overrides)
    if args.tiny:
        overrides = [*TINY_OVERRIDES, *overrides]
        args.window, args.max_episodes, args.nine_episodes = 3, 6, 3
        args.max_minutes = args.nine_max_minutes = 2.0
    cfg = config.load(args.config, overrides)

    print(
        f"SB3 DDPG vs jaxlc on jaxlc/LaneChange-v0 | {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores | {date.today()} | nets {list(cfg.ddpg.hidden)}, "
        f"batch {cfg.ddpg.batch_size}, memory {args.memory} | target {args.target:.0%} over the "
        f"last {args.window} episodes | load {_load()}",
        flush=True,
    )
    single = dict(
        memory=args.memory,
        target=args.target,
        window=args.window,
        max_seconds=args.max_minutes * 60,
        max_episodes=args.max_episodes,
    )
    sb3 = _with_load(run_sb3, cfg, seed=args.seed, **single)
    print(f"  SB3 done: {sb3['episodes']:,} episodes in {sb3['wall_s']:.0f} s", flush=True)
    jx = _with_load(run_jaxlc_one, args.config, overrides, **single)
    print(f"  jaxlc done: {jx['episodes']:,} episodes in {jx['wall_s']:.0f} s", flush=True)

    e = min(args.nine_episodes, sb3["episodes"])
    sb3_one = float(sb3["episode_times"][e - 1]) if e else float("nan")
    grid = _with_load(
        run_jaxlc_grid, args.config, overrides, episodes=e, max_seconds=args.nine_max_minutes * 60
    )
    n = grid["models"]
    sb3_nine = {
        **{k: v for k, v in sb3.items() if k not in ("episode_times", "lrs")},
        "system": f"{sb3['system']} x{n} sequential (EXTRAPOLATED: {n} x one run)",
        "models": n,
        "episodes": e,
        "wall_s": n * sb3_one,
        "time_to_target_s": float("nan"),
        "episode_of_target": float("nan"),
        "success_last_window": float("nan"),
    }

    print()
    head = (
        f"{'':<44} {'updates/s':>10} {'transitions/s':>14} {'trans/update':>13} "
        f"{'episodes':>9} {'wall s':>8} {'compile s':>10} {'load':>11}  "
        f"time to target; last-window success"
    )
    print(head)
    for r in (sb3, jx):
        print(
            f"{r['system'][:44]:<44} {r['updates_per_s']:>10,.0f} {r['transitions_per_s']:>14,.0f} "
            f"{r['transitions'] / max(r['updates'], 1):>13.1f} {r['episodes']:>9,} "
            f"{r['wall_s']:>8.0f} {r['compile_s']:>10.1f} "
            f"{r['load_before']:>5.2f}>{r['load_after']:<5.2f}  "
            f"{_fmt_target(r)}; {r['success_last_window']:.0%}"
        )
    print(
        f"SB3 update alone (torch): {sb3['update_only_per_s']:,.0f}/s; learning rates actor "
        f"{sb3['lrs'][0]:g}, critic {sb3['lrs'][1]:g}"
    )
    print(
        f"\nNine models, {e:,} episodes each:\n"
        f"  jaxlc grid ({n} models side by side): {grid['wall_s']:,.0f} s "
        f"(compile {grid['compile_s']:.0f} s, {grid['updates_per_s']:,.0f} model-updates/s, "
        f"load {grid['load_before']:.2f} -> {grid['load_after']:.2f})\n"
        f"  SB3, {n} runs one after another:      {n * sb3_one:,.0f} s "
        f"(EXTRAPOLATED: {n} x {sb3_one:,.0f} s, the measured run's time to episode {e:,})\n"
        f"  ratio SB3 / jaxlc: {n * sb3_one / grid['wall_s']:.1f}x"
    )
    if math.isfinite(sb3["time_to_target_s"]) and math.isfinite(jx["time_to_target_s"]):
        print(
            f"Time to {args.target:.0%}: SB3 / jaxlc = "
            f"{sb3['time_to_target_s'] / jx['time_to_target_s']:.1f}x"
        )

    rows = [
        {k: v for k, v in r.items() if k not in ("episode_times", "lrs")}
        for r in (sb3, jx, grid, sb3_nine)
    ]
    write_csv(args.csv, rows)
    print(f"wrote {args.csv}")
    return {"sb3": rows[0], "jaxlc": rows[1], "jaxlc_grid": rows[2], "sb3_nine": rows[3]}


if __name__ == "__main__":
    main(sys.argv[1:])
