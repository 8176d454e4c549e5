"""docs/benchmarks.md's GPU section: ``benchmarks/scripts/gpu_benchmarks.sh`` on a GPU and the
same scripts on the CPU from the same commit, each figure beside its machine's matmul peak."""

from __future__ import annotations

from tables.common import BENCHMARKS, csv_rows

GPU_BENCH = BENCHMARKS / "bench_gpu_2026-11-27"  # gpu/ and cpu/: one session each


def _rows(machine: str, name: str) -> tuple[dict[str, str], ...]:
    path = GPU_BENCH / machine / name
    return csv_rows(path) if path.exists() else ()


def _machine(machine: str) -> str:
    """The device line of a side's ``machine.txt`` (its second line)."""
    return (GPU_BENCH / machine / "machine.txt").read_text().splitlines()[1].split(",")[0]


def gpu_table() -> str:
    """The simulator's env-steps/s by envs and the update's grid-updates/s by models, GPU
    beside CPU; a size one side did not run reads "–"."""
    sim = {m: {int(r["envs"]): r for r in _rows(m, "sim_paper.csv")} for m in ("gpu", "cpu")}
    lines = [
        f"| measure | size | GPU ({_machine('gpu')}) | CPU ({_machine('cpu')}) | GPU / CPU |",
        "|---|---|---|---|---|",
    ]
    for n in sorted(sim["gpu"].keys() | sim["cpu"].keys()):
        g, c = (float(sim[m][n]["env_steps_per_s"]) if n in sim[m] else None for m in sim)
        ratio = f"{g / c:,.0f}×" if g and c else "–"
        lines.append(
            f"| simulator env-steps/s (paper's traffic) | {n:,} envs | "
            f"{f'{g:,.0f}' if g else '–'} | {f'{c:,.0f}' if c else '–'} | {ratio} |"
        )
    for models in (9, 90, 900):
        g, c = (_rows(m, f"update_{models}.csv") for m in ("gpu", "cpu"))
        if not (g or c):
            continue
        cell = [
            f"{float(r[0]['grid_updates_per_s']):,.1f} ({float(r[0]['share_of_peak']):.0%} of "
            f"{float(r[0]['peak_gflops']):,.0f} GFLOP/s)"
            if r
            else "–"
            for r in (g, c)
        ]
        ratio = (
            f"{float(g[0]['grid_updates_per_s']) / float(c[0]['grid_updates_per_s']):,.0f}×"
            if g and c
            else "–"
        )
        lines.append(
            f"| DDPG grid-updates/s (share of the matmul peak) | {models} models | {cell[0]} | "
            f"{cell[1]} | {ratio} |"
        )
    return "\n".join(lines)


BLOCKS = {"gpu-bench": gpu_table}
