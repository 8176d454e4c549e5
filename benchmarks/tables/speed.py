"""docs/benchmarks.md's speed figures: the simulator, the update, host devices, the actors,
and the comparisons with highway-env, Rejax and SB3, each from a benchmark session's CSVs
with the matmul peaks measured around its runs."""

from __future__ import annotations

import functools
import re

import numpy as np

from benchmarks.tables.common import BENCHMARKS, csv_rows

BENCH = BENCHMARKS / "bench_cpu_2026-11-24"  # the session every other speed figure is from
ACTORS = BENCHMARKS / "bench_actors_cpu_2026-11-26"  # the plain, odd and paired actors
REJAX = BENCHMARKS / "vs_rejax_cpu"  # Rejax's learners beside jaxlc's DDPG
VALIDATE = BENCHMARKS / "validate_cpu_2026-11-27"  # crude MC's speed, validate_throughput.py


def bench(name: str) -> tuple[dict[str, str], ...]:
    return csv_rows(BENCH / name)


@functools.cache
def _timing() -> dict[str, dict[str, str]]:
    """``timing.txt`` of the benchmark session: per step, its start and end lines' fields."""
    steps: dict[str, dict[str, str]] = {}
    for line in (BENCH / "timing.txt").read_text().splitlines():
        name, what, when, *rest = line.split()
        if what in ("start", "end"):
            fields = dict(zip(rest[::2], rest[1::2], strict=False))
            steps.setdefault(name, {}).update({what: when, **fields})
    return steps


def _peaks(*names: str) -> str:
    """The matmul peaks measured around benchmark steps, as a range in GFLOP/s."""
    t = _timing()
    values = [float(t[n][k]) for n in names for k in ("peak_before_gflops", "peak_after_gflops")]
    return f"{min(values):.0f}–{max(values):.0f} GFLOP/s"


def _table(head: str, body, *after: str) -> str:
    """A markdown table: ``head`` and each row of ``body`` are cells joined by " | "; then
    the paragraphs ``after``, each behind a blank line."""
    lines = [f"| {head} |", "|---" * (head.count(" | ") + 1) + "|"]
    return "\n\n".join(["\n".join(lines + [f"| {row} |" for row in body]), *after])


def sim_table() -> str:
    """``benchmarks/sim_throughput.py``: env-steps/s by batch size."""
    rows = bench("sim_throughput.csv")
    rate = [float(r["env_steps_per_s"]) for r in rows]
    cells = (f"**{x:,.0f}**" if x == max(rate) else f"{x:,.0f}" for x in rate)
    return _table(
        "envs | " + " | ".join(f"{int(r['envs']):,}" for r in rows),
        [
            "env-steps/s | " + " | ".join(cells),
            "RL share of env-steps | " + " | ".join(f"{float(r['rl_share']):.1%}" for r in rows),
        ],
        f"Matmul peak around the run: {_peaks('sim_throughput')}.",
    )


def highway_table() -> str:
    """``vs_highway_env.csv`` (its script retired, at b98c04d): both simulators, the ratios."""
    rows = bench("vs_highway_env.csv")
    names = {
        "single": "one env",
        "sync:2": "`SyncVectorEnv` × 2",
        "async:2": "`AsyncVectorEnv` × 2",
        "async:4": "`AsyncVectorEnv` × 4",
        "gym wrapper": "gym wrapper, one env",
        "scan": "`lax.scan`, one env",
        "scan+vmap": "`lax.scan` + `vmap`",
    }
    rate = {(r["simulator"], r["setting"], r["envs"]): float(r["env_steps_per_s"]) for r in rows}
    hw = {k: v for k, v in rate.items() if k[0] == "highway-env"}
    jx = {k: v for k, v in rate.items() if k[0] == "jaxlc"}
    hw_best, jx_best = max(hw, key=hw.get), max(jx, key=jx.get)
    single = rate[("highway-env", "single", "1")]
    one = rate[("jaxlc", "scan", "1")] / single
    return _table(
        "simulator | setting | envs | env-steps/s | RL decisions/s",
        (
            f"{r['simulator']} | {names.get(r['setting'], r['setting'])} | {int(r['envs']):,} | "
            f"{float(r['env_steps_per_s']):,.0f} | {float(r['decisions_per_s']):,.0f}"
            for r in rows
        ),
        f"One jaxlc env (`lax.scan`) runs {one:,.0f}× one highway-env env; jaxlc's best batch "
        f"({int(jx_best[2]):,} envs) runs {jx[jx_best] / hw[hw_best]:,.0f}× highway-env's best "
        f"setting ({names[hw_best[1]]}) and {jx[jx_best] / single:,.0f}× "
        f"its single env. Matmul peak around the run: {_peaks('vs_highway_env')}.",
    )


def update_table() -> str:
    """``benchmarks/update_throughput.py`` on 1 and on 3 host devices, and one
    update's parts."""
    runs = {int(r["devices"]): r for r in bench("update_throughput.csv")}  # 1 and 3 devices
    one = {k: float(v) for k, v in runs[1].items() if k.endswith(("ms", "gbps", "peak", "ceiling"))}
    parts = _table(
        "part of one grid update (9 models, 1 device) | time | what it reaches",
        [
            f"the whole update | {one['update_ms']:.2f} ms | "
            f"{one['share_of_peak']:.1%} of the peak",
            f"its matrix products alone, at their shapes | {one['products_alone_ms']:.2f} ms | "
            f"{one['products_alone_share_of_peak']:.1%} of the peak",
            f"its Adam + soft-target pass alone | {one['optimizer_alone_ms']:.2f} ms | "
            f"{one['optimizer_alone_gbps']:.1f} GB/s at the minimum 36 bytes per parameter",
            "a plain streamed `a + 1e-3 b` over the same footprint | – | "
            f"{one['stream_gbps']:.1f} GB/s",
            "an update of nothing but the products and a streamed Adam pass (`share_ceiling`) | – "
            f"| {one['share_ceiling']:.1%} of the peak",
        ],
    )
    return _table(
        "models laid over | grid-updates/s | MFLOP per model update | achieved GFLOP/s | "
        "matmul peak, same process | share of peak",
        (
            f"{n} device{'s' if n > 1 else ''} | {float(r['grid_updates_per_s']):.1f} | "
            f"{float(r['mflop_per_model_update']):.0f} | {float(r['achieved_gflops']):.1f} | "
            f"{float(r['peak_gflops']):.1f} | **{float(r['share_of_peak']):.0%}**"
            for n, r in runs.items()
        ),
        parts,
        f"Matmul peak around the runs: {_peaks('update_throughput_1dev', 'update_throughput_3dev')}"
        " (the table's own column is the one measured inside each run).",
    )


def actors_table() -> str:
    """``update_throughput.py actors`` (a mode retired, at b98c04d): the plain actor, the
    reflection-odd one and the odd one on paired batches side by side, each run beside the
    matmul peaks measured around it."""
    rows = csv_rows(ACTORS / "actors.csv")

    def against_plain(actor: str, name: str) -> str:
        sweep, update, flops = (
            np.mean([float(r[k]) for r in rows if r["actor"] == actor])
            / np.mean([float(r[k]) for r in rows if r["actor"] == "plain"])
            for k in ("sweep_env_steps_per_s", "grid_updates_per_s", "mflop_per_model_update")
        )
        return (
            f"{name} **{sweep:.1%}** of the plain actor's env-steps/s in the default sweep and "
            f"{update:.1%} of its grid-updates/s, at {flops:.2f}× its matrix-product FLOPs per "
            "update"
        )

    rows_ = against_plain("odd", "the odd actor on rows (`odd`, the default until 2026-11-26)")
    pairs = against_plain("paired", "on reflection pairs (`paired`, today's default)")
    return _table(
        "round | actor | MFLOP per model update | grid-updates/s | peak around the update "
        "(GFLOP/s) | default sweep env-steps/s | its wall s | peak at its end (GFLOP/s)",
        (
            f"{r['round']} | {r['actor']} | {float(r['mflop_per_model_update']):.0f} | "
            f"{float(r['grid_updates_per_s']):.1f} | {float(r['peak_gflops_before_update']):.0f}"
            f"–{float(r['peak_gflops_after_update']):.0f} | "
            f"{float(r['sweep_env_steps_per_s']):,.0f} | {float(r['sweep_wall_s']):.1f} | "
            f"{float(r['sweep_peak_gflops']):.0f}"
            for r in rows
        ),
        f"Over the rounds: {rows_}; {pairs}.",
    )


def devices_table() -> str:
    """``benchmarks/devices_throughput.py``, one process per device count, both grids
    (``devices.csv``: the six runs' CSVs, one ``grid`` and ``n`` column apart)."""
    counts, body, steps = (1, 2, 3), [], []
    for grid, what in (
        ("paper", "paper (9 models, 300/600, batch 64)"),
        ("smoke", "smoke (4 models, 32/32, batch 16)"),
    ):
        rows = {int(r["n"]): r for r in bench("devices.csv") if r["grid"] == grid}
        updates = {n: float(rows[n]["grid_updates_per_s"]) for n in counts}
        best = max(counts, key=updates.get)
        for key, unit, form in (
            ("grid_updates_per_s", "grid-updates/s", "{:,.1f}"),
            ("env_steps_per_s", "env-steps/s", "{:,.0f}"),
        ):
            cells = {n: form.format(float(rows[n][key])) for n in counts}
            cells[best] = f"**{cells[best]}**"
            body.append(f"{what}: {unit} | " + " | ".join(cells.values()))
        against = (f"{updates[n] / updates[1]:.2f}×" for n in counts)
        body.append(f"{what}: against one device | " + " | ".join(against))
        steps += [f"devices_{grid}_n{n}" for n in counts]
    return _table(
        "grid | " + " | ".join(f"N = {n}" for n in counts),
        body,
        f"Matmul peak around the runs: {_peaks(*steps)}.",
    )


def rejax_table() -> str:
    """``benchmarks/vs_rejax.py``'s rows beside jaxlc's DDPG ④ over 3 seeds: success on the
    100 fixed cases at the end, return, wall time, decisions per second, the machine's peak."""
    ddpg = [r for r in csv_rows(REJAX / "ddpg_d4_s3_eval.csv") if r["episode"] == "5000"]
    success = [int(r["success"]) / int(r["performed"]) for r in ddpg]
    summary = (REJAX / "ddpg_d4_s3_summary.md").read_text()
    wall, steps, peak = (
        float(x.replace(",", ""))
        for x in re.search(r"Wall time (\d+) s, ([\d,]+) env-steps.* (\d+) GFLOP", summary).groups()
    )
    body = [
        f"**jaxlc DDPG ④** (k = 1, D = 4000, the defaults of then) | not recorded: 5000 "
        f"episodes, {steps / 3 / 1e6:.2f} M env-steps (traffic included) | "
        f"**{100 * np.mean(success):.1f}%** [{100 * min(success):.1f}, {100 * max(success):.1f}] "
        f"({', '.join(f'{x:.2f}' for x in success)}) | "
        f"{np.mean([float(r['avg_return']) for r in ddpg]):.1f} | {wall:.0f} s (compile "
        f"included) | – | {peak:.0f} GFLOP/s"
    ]
    names = {"ppo": "Rejax PPO (`normalize_rewards`)", "td3": "Rejax TD3", "sac": "Rejax SAC"}
    for r in csv_rows(REJAX / "vs_rejax.csv"):
        body.append(
            f"{names[r['learner'].removeprefix('rejax ')]} | "
            f"{int(r['decisions_per_seed']) // 1000} k | "
            f"{100 * float(r['success_mean']):.1f}% [{100 * float(r['success_lo']):.1f}, "
            f"{100 * float(r['success_hi']):.1f}] ({', '.join(r['success_per_seed'].split())}) | "
            f"{float(r['return_mean']):.1f} | "
            f"{float(r['train_s']):.0f} s (+ {float(r['compile_s']):.1f} s compile) | "
            f"{int(r['decisions_per_s']):,} | {r['matmul_peak_gflops']} GFLOP/s"
        )
    return _table(
        "learner | decisions per seed | success, mean [seeds' range] (per seed) | return | "
        "wall, 3 seeds in one program | decisions/s | matmul peak",
        body,
    ).replace("| -", "| −")


def scripted_noise_table() -> str:
    """``benchmarks/scripted_under_noise.py``: the scripted controller's success under the
    training noise, by k and σ, with the lane changes behind each figure."""
    rows = bench("scripted_under_noise.csv")
    sigmas = list(dict.fromkeys(r["sigma"] for r in rows))
    at = {(r["k"], r["sigma"]): r for r in rows}
    ends = [sum(int(r[e]) for r in rows) for e in ("timeout", "out_of_bounds", "collision")]
    failed = sum(int(r["lane_changes"]) - int(r["success"]) for r in rows)
    return _table(
        "k | " + " | ".join(f"σ = {float(x):g}" for x in sigmas),
        (
            f"{k} | "
            + " | ".join(
                f"{100 * float(c['success_rate']):.2f}% (of {int(c['lane_changes']):,})"
                for c in (at[k, x] for x in sigmas)
            )
            for k in dict.fromkeys(r["k"] for r in rows)
        ),
        f"Of the {failed:,} lane changes that failed, {ends[0]:,} timed out, {ends[1]:,} went out "
        f"of bounds and {ends[2]:,} collided.",
    )


def time_to_solution() -> str:
    """``benchmarks/time_to_solution.py`` on the default study: one sentence from its
    CSV."""
    (r,) = bench("time_to_solution.csv")
    t = _timing()["time_to_solution"]
    if r["reached"] != "True":
        return f"Not reached within {float(r['wall_s']):.0f} s on {r['devices']} host devices."
    return (
        f"**{float(r['wall_s']):.1f} s** on {r['devices']} host devices ({r['date']}); the "
        f"machine's float32 matmul peak measured {r['matmul_peak_gflops']} GFLOP/s inside the "
        f"run and {float(t['peak_before_gflops']):.0f}–{float(t['peak_after_gflops']):.0f} "
        f"GFLOP/s right before and after it. {r['model']} seed {r['seed']} reached "
        f"{float(r['success_last']):.0%} at episode {int(r['episode']):,}, after "
        f"{int(r['env_steps']) / 1e6:.2f} M env-steps of the {r['models']} models."
    )


def sb3_table() -> str:
    """``vs_sb3.csv`` (its script retired, at b98c04d): one model of each learner to the
    target, then nine models to the episode SB3 reached (jaxlc's grid measured, SB3's nine
    runs extrapolated from one)."""
    sb3, jx, grid, sb3_nine = bench("vs_sb3.csv")  # both single models reached the target
    ratio = float(sb3_nine["wall_s"]) / float(grid["wall_s"])
    faster = float(sb3["time_to_target_s"]) / float(jx["time_to_target_s"])
    return _table(
        "one model | updates/s | RL transitions/s | transitions per update | compile s | "
        "time to the target",
        (
            f"{who} | {float(r['updates_per_s']):,.0f} | {float(r['transitions_per_s']):,.0f} | "
            f"{int(r['transitions']) / max(int(r['updates']), 1):.1f} | "
            f"{float(r['compile_s']):.1f} | {float(r['time_to_target_s']):.0f} s (episode "
            f"{int(float(r['episode_of_target'])):,})"
            for who, r in (("SB3 DDPG, one env", sb3), ("jaxlc, 32 envs", jx))
        ),
        f"To the target, one jaxlc model was {faster:.1f}× faster than one SB3 model (in more "
        "episodes: it makes fewer updates per transition).",
        f"Nine models to episode {int(sb3_nine['episodes']):,} each: the jaxlc grid took "
        f"{float(grid['wall_s']):.0f} s (measured); nine SB3 runs one after another would take "
        f"{float(sb3_nine['wall_s']):.0f} s (extrapolated: 9 × the measured run's time to that "
        f"episode): {ratio:.1f}×, at equal episodes, not at equal success. Matmul peak around "
        f"the run: {_peaks('vs_sb3')}.",
    )


def validate_speed_table() -> str:
    """Crude MC's lane changes per second and its env-steps per second against the
    simulator's at the same envs (``validate_throughput.py``'s CSV: a session per date)."""
    rows = csv_rows(VALIDATE / "throughput_hazards.csv")
    names = {
        "paper": "the paper's",
        "braking": "braking events (2 per vehicle-hour)",
        "hazards": "MOBIL lane changes and braking events (SPEC's rates)",
    }

    def count(n: str) -> str:
        return f"{int(n):,}" if n else "–"

    def share(r: dict) -> str:
        return f"{100 * float(r['share_of_sim']):.1f}%" if r["share_of_sim"] else "–"

    def peaks(day: str) -> str:
        p = [
            int(r[k])
            for r in rows
            if r["date"] == day
            for k in ("matmul_peak_before", "matmul_peak_after")
        ]
        return f"{day}: {min(p)}–{max(p)}"

    return _table(
        f"date | traffic, {int(rows[0]['envs']):,} envs | lane changes per case | lane changes/s "
        "per model | MC env-steps/s | `sim_throughput.py` env-steps/s | share (target ≥ 50%)",
        (
            f"{r['date']} | {names[r['traffic']]} | {r['chain']} | "
            f"{float(r['lane_changes_per_s']):,.1f} | "
            f"{count(r['env_steps_per_s'])} | "
            f"{int(r['sim_env_steps_per_s']):,} | {share(r)}"
            for r in rows
        ),
        "The idle 2-core VM, matmul peak (GFLOP/s) "
        + "; ".join(peaks(d) for d in dict.fromkeys(r["date"] for r in rows))
        + ". MC's env-steps count the warm-up's traffic-only steps; a chain's (several lane "
        "changes per case in one traffic, `validate --chain`) are not counted.",
    )


BLOCKS = {
    "sim": sim_table,
    "highway": highway_table,
    "update": update_table,
    "actors": actors_table,
    "devices": devices_table,
    "rejax": rejax_table,
    "sb3": sb3_table,
    "scripted-noise": scripted_noise_table,
    "time-to-solution": time_to_solution,
    "validate-speed": validate_speed_table,
}
