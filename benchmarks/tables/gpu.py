"""docs/benchmarks.md's GPU section: ``benchmarks/gpu_benchmarks.sh`` on a GPU and the
same scripts on the CPU from the same commit, each figure beside its machine's matmul peak."""

from __future__ import annotations

import json
from collections.abc import Callable

from benchmarks.tables.common import BENCHMARKS, csv_rows

GPU_BENCH = BENCHMARKS / "bench_gpu_2026-11-27"  # gpu/ and cpu/: one session each
SIDES = ("gpu", "cpu")


def _read(side: str, name: str):
    """A side's CSV rows or JSON document; None where that side did not run it."""
    path = GPU_BENCH / side / name
    if not path.exists():
        return None
    return csv_rows(path) if path.suffix == ".csv" else json.loads(path.read_text())


def _by(name: str, column: str | None = None) -> dict[int, list]:
    """Both sides' entries of a file that holds several runs (a CSV's rows by ``column``, a
    JSON's by key), by that size in ascending order; None where a side did not run it."""
    sides = [_read(s, name) or {} for s in SIDES]
    runs = [
        {int(r[column]): r for r in x} if column else {int(k): v for k, v in x.items()}
        for x in sides
    ]
    return {n: [r.get(n) for r in runs] for n in sorted(runs[0].keys() | runs[1].keys())}


def _machine(side: str) -> str:
    """The device line of a side's ``machine.txt`` (its second line)."""
    return (GPU_BENCH / side / "machine.txt").read_text().splitlines()[1].split(",")[0]


def _row(
    measure: str, size: str, cells: list, value: Callable[[object], float], text: Callable
) -> str:
    """One table line: each side's cell as ``text(cell)`` ("–" where it did not run) and the
    GPU / CPU ratio of ``value``."""
    g, c = cells
    r = value(g) / value(c) if g and c else None
    ratio = "–" if r is None else f"{r:,.1f}×" if r < 10 else f"{r:,.0f}×"
    return f"| {measure} | {size} | {text(g) if g else '–'} | {text(c) if c else '–'} | {ratio} |"


def _sim_rows(name: str, traffic: str) -> list[str]:
    return [
        _row(
            f"simulator env-steps/s ({traffic})",
            f"{n:,} envs",
            pair,
            lambda r: float(r["env_steps_per_s"]),
            lambda r: f"{float(r['env_steps_per_s']):,.0f}",
        )
        for n, pair in _by(name, "envs").items()
    ]


def _update_row(models: int, pair: list) -> str:
    return _row(
        "DDPG grid-updates/s (achieved; the matmul peak in the same process)",
        f"{models} models",
        pair,
        lambda r: float(r["grid_updates_per_s"]),
        lambda r: (
            f"{float(r['grid_updates_per_s']):,.1f} ({float(r['achieved_gflops']):,.0f} GFLOP/s; "
            f"the 2048² matmul {float(r['peak_gflops']):,.0f})"
        ),
    )


def sweep_steady(d: dict) -> float:
    """A sweep's env-steps/s after its first chunk (which holds the compilation)."""
    first = d["chunk_steps"] * d["envs_per_model"] * d["models"]
    return (d["env_steps"] - first) / (d["wall_s"] - d["first_chunk_s"])


def _sweep_row(seeds: int, cells: list) -> str:
    eps = next(d["episodes_per_model"] for d in cells if d)
    return _row(
        f"default sweep, {eps} episodes per model: wall (its first chunk, compiling)",
        f"{seeds} seed{'s' * (seeds > 1)} per cell ({9 * seeds} models)",
        cells,
        lambda d: 1 / d["wall_s"],
        lambda d: (
            f"{d['wall_s']:,.1f} s (first chunk {d['first_chunk_s']:,.1f} s); "
            f"{sweep_steady(d):,.0f} env-steps/s after it"
        ),
    )


def _heldout_row(policies: int, cells: list) -> str:
    def rate(r: dict) -> float:
        return int(r["policies"]) * int(r["lane_changes"]) / float(r["rollouts_s"])

    lane_changes = next(int(r["lane_changes"]) for r in cells if r)
    return _row(
        "held-out evaluation: policy-lane-changes/s, compilation included (drawing the cases, s)",
        f"{policies} policies × {lane_changes:,}",
        cells,
        rate,
        lambda r: f"{rate(r):,.0f} ({float(r['cases_s']):,.1f} s)",
    )


def _validate_row() -> str:
    cells = [
        (_read(s, "validate_keys0/validate.json") or {"models": [None]})["models"][0] for s in SIDES
    ]
    return _row(
        "validation, crude Monte Carlo: lane changes/s, compilation included (lane changes, s)",
        "④, the paper's traffic",
        cells,
        lambda m: m["lane_changes_per_s"],
        lambda m: f"{m['lane_changes_per_s']:,.0f} ({m['lane_changes']:,} in {m['wall_s']:,.1f} s)",
    )


def gpu_table() -> str:
    """Every figure of the GPU section, GPU beside CPU; a size one side did not run reads
    "–"."""
    lines = [
        f"| measure | size | GPU ({_machine('gpu')}) | CPU ({_machine('cpu')}) | GPU / CPU |",
        "|---|---|---|---|---|",
        *_sim_rows("sim_paper.csv", "the paper's traffic"),
        *_sim_rows("sim_hazards.csv", "MOBIL lane changes and braking events"),
        *(_update_row(m, p) for m, p in _by("update.csv", "models").items()),
        *(_sweep_row(n, p) for n, p in _by("sweeps.json").items()),
        *(_heldout_row(n, p) for n, p in _by("cost.csv", "policies").items()),
        _validate_row(),
    ]
    return "\n".join(lines)


BLOCKS = {"gpu-bench": gpu_table}
