"""A run's ``summary.md``: its speed, on the machine that gave it, and each model's last
episodes (written by the sweep and by ``jaxlc.study.merge``)."""

from __future__ import annotations

from typing import Any


def summary_markdown(summary: dict[str, Any], last: int = 100) -> str:
    """The summary as markdown: one line of speed, with the machine that gave it, and a table."""
    rows, wall_s, env_steps = summary["models"], summary["wall_s"], summary["env_steps"]
    lines = [
        f"Wall time {wall_s:.0f} s, {env_steps:,} env-steps ({env_steps / wall_s:,.0f}/s), "
        f"{sum(r['episodes'] for r in rows):,} episodes "
        f"({sum(r['episodes'] for r in rows) / wall_s:.1f}/s), on {summary['devices']} "
        f"{summary['device']} device(s); float32 matmul peak of this machine "
        f"{summary['matmul_peak_gflops']:.0f} GFLOP/s.",
        "",
        f"| model | seed | episodes | success (last {last}) | return (last {last}) | "
        f"manoeuvre steps | out of bounds / collision / timeout |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        e = r["ends_last"]
        lines.append(
            f"| {r['label']} | {r['seed']} | {r['episodes']} | {r['success_rate_last']:.1%} | "
            f"{r['return_last']:.1f} | {r['steps_last']:.1f} | "
            f"{e['out_of_bounds']} / {e['collision']} / {e['timeout']} |"
        )
    return "\n".join(lines) + "\n"
