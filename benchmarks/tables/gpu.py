"""docs/benchmarks.md's GPU section: ``benchmarks/gpu_benchmarks.sh`` on a GPU and the
same scripts on the CPU from the same commit, each figure beside its machine's matmul peak."""

from __future__ import annotations

import json
from collections.abc import Callable

from benchmarks.tables.common import BENCHMARKS, csv_rows

GPU_BENCH = BENCHMARKS / "bench_gpu_2026-11-27"  # gpu/ and cpu/: one session each
SIDES = ("gpu", "cpu")


def _rows(side: str, name: str) -> tuple[dict[str, str], ...]:
    path = GPU_BENCH / side / name
    return csv_rows(path) if path.exists() else ()


def _json(side: str, name: str) -> dict | None:
    path = GPU_BENCH / side / name
    return json.loads(path.read_text()) if path.exists() else None


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
    sim = {s: {int(r["envs"]): r for r in _rows(s, name)} for s in SIDES}
    return [
        _row(
            f"simulator env-steps/s ({traffic})",
            f"{n:,} envs",
            [sim[s].get(n) for s in SIDES],
            lambda r: float(r["env_steps_per_s"]),
            lambda r: f"{float(r['env_steps_per_s']):,.0f}",
        )
        for n in sorted(sim["gpu"].keys() | sim["cpu"].keys())
    ]


def _update_rows() -> list[str]:
    def text(r: dict) -> str:
        return (
            f"{float(r['grid_updates_per_s']):,.1f} ({float(r['achieved_gflops']):,.0f} GFLOP/s; "
            f"the 2048² matmul {float(r['peak_gflops']):,.0f})"
        )

    cells = {
        m: [next(iter(_rows(s, f"update_{m}.csv")), None) for s in SIDES] for m in (9, 90, 900)
    }
    return [
        _row(
            "DDPG grid-updates/s (achieved; the matmul peak in the same process)",
            f"{models} models",
            pair,
            lambda r: float(r["grid_updates_per_s"]),
            text,
        )
        for models, pair in cells.items()
        if any(pair)
    ]


def sweep_steady(d: dict) -> float:
    """A sweep's env-steps/s after its first chunk (which holds the compilation)."""
    first = d["chunk_steps"] * d["envs_per_model"] * d["models"]
    return (d["env_steps"] - first) / (d["wall_s"] - d["first_chunk_s"])


def _sweep_rows() -> list[str]:
    def text(d: dict) -> str:
        return (
            f"{d['wall_s']:,.1f} s (first chunk {d['first_chunk_s']:,.1f} s); "
            f"{sweep_steady(d):,.0f} env-steps/s after it"
        )

    rows = []
    for seeds in (1, 10, 100):
        cells = [_json(s, f"sweep_s{seeds}.json") for s in SIDES]
        if not any(cells):
            continue
        eps = next(d["episodes_per_model"] for d in cells if d)
        rows.append(
            _row(
                f"default sweep, {eps} episodes per model: wall (its first chunk, compiling)",
                f"{seeds} seed{'s' * (seeds > 1)} per cell ({9 * seeds} models)",
                cells,
                lambda d: 1 / d["wall_s"],
                text,
            )
        )
    return rows


def _heldout_row() -> str:
    def rate(r: dict) -> float:
        return int(r["policies"]) * int(r["lane_changes"]) / float(r["rollouts_s"])

    cells = [next(iter(_rows(s, "cost.csv")), None) for s in SIDES]
    size = next(f"{r['policies']} policies × {int(r['lane_changes']):,}" for r in cells if r)
    return _row(
        "held-out evaluation: policy-lane-changes/s, compilation included (drawing the cases, s)",
        size,
        cells,
        rate,
        lambda r: f"{rate(r):,.0f} ({float(r['cases_s']):,.1f} s)",
    )


def _validate_row() -> str:
    def model(d: dict) -> dict:
        return d["models"][0]

    cells = [_json(s, "validate_keys0/validate.json") for s in SIDES]
    return _row(
        "validation, crude Monte Carlo: lane changes/s, compilation included (lane changes, s)",
        "④, the paper's traffic",
        cells,
        lambda d: model(d)["lane_changes_per_s"],
        lambda d: (
            f"{model(d)['lane_changes_per_s']:,.0f} ({model(d)['lane_changes']:,} in "
            f"{model(d)['wall_s']:,.1f} s)"
        ),
    )


def gpu_table() -> str:
    """Every figure of the GPU section, GPU beside CPU; a size one side did not run reads
    "–"."""
    lines = [
        f"| measure | size | GPU ({_machine('gpu')}) | CPU ({_machine('cpu')}) | GPU / CPU |",
        "|---|---|---|---|---|",
        *_sim_rows("sim_paper.csv", "the paper's traffic"),
        *_sim_rows("sim_hazards.csv", "MOBIL lane changes and braking events"),
        *_update_rows(),
        *_sweep_rows(),
        _heldout_row(),
        _validate_row(),
    ]
    return "\n".join(lines)


BLOCKS = {"gpu-bench": gpu_table}
