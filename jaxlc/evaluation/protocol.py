"""The evaluation protocol (``python -m jaxlc.evaluate`` is its command line): which
checkpoints a run's evaluation takes (``select_checkpoints``, ``final_checkpoints``), every
policy on the protocol's fixed cases (``evaluate_run``) and on the held-out lane changes
(``evaluate_heldout``), the learning-speed study (``write_convergence``), the statistics over
seeds (``write_seed_stats``), two runs compared (``compare_runs``), and the files each writes
under ``RUN_DIR/eval/`` (the cases themselves: ``jaxlc.evaluation.cases``; what a row holds:
``jaxlc.evaluation.results``).

Outcome buckets are the reason codes of ``jaxlc.sim.reward`` with 0 read as "unfinished" (hit
the step cap), so every case lands in exactly one bucket.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxlc import config
from jaxlc.evaluation import convergence, heldout, measures, stats
from jaxlc.evaluation.cases import (
    PROTOCOL,
    CaseInfo,
    cases_for_lane_changes,
    evaluate_policies,
    init_actor,
)
from jaxlc.evaluation.numbers import read, write, write_csv
from jaxlc.evaluation.results import (
    CHOICE,
    OUTCOMES,
    SCRIPTED,
    Choice,
    EvalError,
    EvalResult,
    Heldout,
    Norm,
    Policy,
    Row,
    eval_fields,
    final_rows,
    summarise,
)
from jaxlc.evaluation.safety import COUNTED, NORMS
from jaxlc.study import checkpoint
from jaxlc.study.rundir import RunDir, checkpoint_network


def default_episodes(every: int, final: int) -> list[int]:
    """The paper's checkpoint choice (100, 400, 800, ..., 4800, 5000 for every=100, 5000
    episodes) for any spacing: the first, every 4th, and the last."""
    return sorted({every, *range(4 * every, final + 1, 4 * every), final})


def _run_config(run_dir: Path) -> config.Config:
    if not RunDir(run_dir).is_run():
        raise EvalError(
            f"{run_dir} has no config.toml, so it is not a run directory; "
            "pass the --out directory of python -m jaxlc.sweep"
        )
    return RunDir(run_dir).load_config()


def select_checkpoints(
    run_dir: Path, episodes: Sequence[int] | None = None, model: int | None = None
) -> list[tuple[Path, dict[str, Any]]]:
    """``(path, meta)`` of the checkpoints to evaluate, by model then episode.

    ``episodes=None``: ``default_episodes`` of the run's checkpoint spacing up to each
    model's last checkpoint."""
    found = RunDir(run_dir).saved_checkpoints()
    if model is not None:
        found = [(p, m) for p, m in found if m.get("model") == model]
        if not found:
            raise EvalError(f"no checkpoints of model {model} in {run_dir}; see its checkpoints/")
    have = sorted({m["episode"] for _, m in found})
    if episodes is not None:
        chosen = [(p, m) for p, m in found if m["episode"] in set(episodes)]
        if not chosen:
            raise EvalError(
                f"none of the episodes {sorted(episodes)} has a checkpoint; there are {have}"
            )
        return chosen
    every = have[0] if len(have) == 1 else int(min(np.diff(have)))
    # Per model, so one that stopped early still has its own last checkpoint evaluated.
    want = {i: set(default_episodes(every, e)) for i, e in _last_episodes(found).items()}
    chosen = [(p, m) for p, m in found if m["episode"] in want[m["model"]]]
    return chosen or found


def _last_episodes(found: list[tuple[Path, dict[str, Any]]]) -> dict[int, int]:
    """Each model's last checkpoint episode."""
    last: dict[int, int] = {}
    for _, m in found:
        last[m["model"]] = max(last.get(m["model"], 0), m["episode"])
    return last


def _row_meta(path: Path, meta: dict[str, Any], run_dir: Path | None) -> Policy:
    shown = path.relative_to(run_dir) if run_dir and path.is_relative_to(run_dir) else path
    named = [f for f in Policy.__dataclass_fields__ if f != "checkpoint"]
    return Policy(**{k: meta.get(k) for k in named}, checkpoint=str(shown))


def load_rows(
    run_dir: Path, chosen: list[tuple[Path, dict[str, Any]]]
) -> tuple[config.Config, list[Any], list[Policy]]:
    """``(config, actors, metas)`` of the ``chosen`` checkpoints of ``run_dir``: the run's
    config, their actor params (shapes checked against it) and the rows' ``Policy``, the
    scripted baseline first."""
    cfg = _run_config(run_dir)
    shapes = checkpoint.shapes_of(init_actor(cfg))
    actors = [checkpoint.load(p, expect_shapes=shapes)[0] for p, _ in chosen]
    metas = [SCRIPTED] + [_row_meta(p, m, run_dir) for p, m in chosen]
    return cfg, actors, metas


def evaluate_run(
    run_dir: Path,
    episodes: Sequence[int] | None = None,
    *,
    cases: int = PROTOCOL.cases,
    model: int | None = None,
    seed: int = 0,
    max_steps: int = PROTOCOL.max_steps,
    chunk: int = PROTOCOL.chunk,
    traced: int = PROTOCOL.traced,
    devices: int = 1,
) -> EvalResult:
    """Evaluate a run's checkpoints and the scripted baseline (row 0); writes
    ``run_dir/eval/eval.json``, ``eval.csv``, ``cases.npz``, ``traces.npz``; returns the
    JSON's content."""
    run_dir, rd = Path(run_dir), RunDir(run_dir)
    chosen = select_checkpoints(run_dir, episodes, model)
    cfg, actors, metas = load_rows(run_dir, chosen)
    kw = dict(cases=cases, seed=seed, max_steps=max_steps, chunk=chunk, traced=traced)
    out, trace, info = evaluate_policies(
        cfg, [None, *actors], [1] + [m.k for m in metas[1:]], devices=devices, **kw
    )
    result = _result(cfg, out, info, metas, seed, max_steps)
    _write(rd.eval, "eval", result, cfg)
    write_seed_stats(rd.eval, result.rows)
    ids = _policy_ids(metas)
    rd.save_npz(rd.cases, {**out, **ids, **info.as_dict()})
    traced_side = info.side[info.traced]
    rd.save_npz(rd.traces, {**trace, **ids, "traced": info.traced, "side": traced_side})
    return result


def final_checkpoints(
    run_dir: Path, episodes: Sequence[int] | None = None, chosen: bool = True
) -> list[tuple[Path, dict[str, Any]]]:
    """Each model's policy, and the checkpoints of ``episodes`` too, by model then episode: its
    last checkpoint, or with ``chosen`` the one ``eval/choice.json`` names where the run has
    one (``python -m jaxlc.evaluate RUN --choose``; ``results.Choice``)."""
    rd = RunDir(run_dir)
    found = rd.saved_checkpoints()
    last, want = _last_episodes(found), set(episodes or ())
    if chosen and (rd.eval / CHOICE).is_file():
        last.update({int(m): e for m, e in read(rd.eval / CHOICE, Choice).episode.items()})
        saved = {(m["model"], m["episode"]) for _, m in found}
        lack = [f"model {m} episode {e}" for m, e in last.items() if (m, e) not in saved]
        if lack:  # else that model would drop out of every evaluation without a word
            raise EvalError(
                f"{rd.eval / CHOICE} names checkpoints the run lacks ({', '.join(lack)}); "
                "run python -m jaxlc.evaluate RUN --choose again"
            )
    return [(p, m) for p, m in found if m["episode"] in want | {last[m["model"]]}]


def evaluate_heldout(
    run_dir: Path,
    episodes: Sequence[int] | None = None,
    *,
    lane_changes: int = PROTOCOL.lane_changes,
    seed: int = 0,
    max_steps: int = PROTOCOL.max_steps,
    chunk: int = PROTOCOL.chunk,
    devices: int = 1,
    traffic: Sequence[str] = (),
    tag: str = "",
    chosen: bool = True,
) -> Heldout:
    """Every model's policy (its final checkpoint, or the one ``--choose`` chose; and those
    of ``episodes``) and the scripted baseline on ``lane_changes`` held-out lane changes
    (``jaxlc.evaluation.heldout``); writes ``eval/heldout.json``, ``heldout.csv``,
    ``heldout_cells.csv``, ``collisions.csv`` and ``heldout_cases.npz``; returns the JSON's
    content.

    ``traffic``: ``[env]`` overrides (``env.KEY=VALUE``) under which the lane changes are
    driven, in place of the training's traffic, checked as any config value; the files then
    go to ``eval/heldout_TAG/`` (``tag``, default ``traffic``). ``chosen=False``: the final
    checkpoints whatever ``--choose`` chose (``final_checkpoints``)."""
    run_dir, rd = Path(run_dir), RunDir(run_dir)
    cfg, actors, metas = load_rows(run_dir, final_checkpoints(run_dir, episodes, chosen))
    out_dir = rd.eval
    if traffic:
        cfg = heldout.in_traffic(cfg, traffic)
        out_dir = rd.eval / f"heldout_{tag or 'traffic'}"
    keys, started = cases_for_lane_changes(cfg, lane_changes, seed, max_steps)
    out, _, info = evaluate_policies(
        cfg,
        [None, *actors],
        [1] + [m.k for m in metas[1:]],
        started=started,
        max_steps=max_steps,
        chunk=chunk,
        traced=0,
        devices=devices,
    )
    dt = cfg.env.dt
    rows = [heldout.model_row(out, info, p, dt, m) for p, m in enumerate(metas)]
    cells = heldout.cell_rows(final_rows(rows))
    extra = [m.name for m in measures.registered() if m.heldout]
    result = Heldout(
        cfg.hash(),
        seed,
        # the stream's name as every committed heldout.json gives it (keys.stream(seed,
        # HELDOUT, range(n)) since; jaxlc.evaluation.keys says so), so the files stay alike
        f"jaxlc.evaluation.cases.heldout_keys({seed}, {len(keys)})",
        len(keys),
        int(info.performed.sum()),
        [Norm(*n) for n in NORMS],
        COUNTED,
        heldout.traffic_of(cfg.env),
        list(traffic),
        rows,
        cells,
        heldout.claim_d(cells),
        heldout.collisions(out, info, metas, dt),
        # measures of your own: the report's table shows them (none: the files as ever)
        extra or None,
    )
    write(out_dir / rd.heldout_json.name, result)
    write_csv(out_dir / "heldout.csv", rows, heldout.fields())
    write_csv(out_dir / "heldout_cells.csv", cells)
    write_csv(out_dir / "collisions.csv", result.collisions, heldout.COLLISION_FIELDS)
    ids = _policy_ids(metas)
    rd.save_npz(out_dir / rd.heldout_cases.name, {**out, **ids, **info.as_dict()})
    return result


def write_convergence(run_dir: Path) -> convergence.Convergence | None:
    """``eval/convergence.json`` and ``convergence.csv``: the learning-speed measures of every
    model from its training curves and the paper's comparisons on them
    (``jaxlc.evaluation.convergence``); None when the run has no episode metrics."""
    rd = RunDir(run_dir)
    episodes = rd.load_npz(rd.episodes)
    if episodes is None or not rd.summary_json.is_file():
        return None
    doc = convergence.study(episodes, rd.read_json(rd.summary_json)["models"])
    write(rd.convergence, doc)
    write_csv(rd.eval / "convergence.csv", doc.models)
    return doc


def evaluate_checkpoint(
    path: Path,
    run_dir: Path | None = None,
    *,
    cases: int = PROTOCOL.cases,
    seed: int = 0,
    max_steps: int = PROTOCOL.max_steps,
) -> EvalResult:
    """Evaluate one checkpoint file and the scripted baseline; writes
    ``eval/<model dir>_<stem>.json`` (+ ``.csv``) in its run directory (or beside the file).

    The config is the run directory's (given, or the file's ``../../``); a lone file gets the
    default env and the network it holds."""
    path = Path(path)
    up = path.resolve().parents
    if run_dir is None and len(up) > 2 and RunDir(up[2]).is_run():
        run_dir = up[2]
    params, meta = checkpoint.load(path)
    if run_dir is not None:
        cfg = _run_config(Path(run_dir))
        checkpoint.load(path, expect_shapes=checkpoint.shapes_of(init_actor(cfg)))
    else:
        hidden, symmetric = checkpoint_network(path, meta)
        cfg = config.load(
            None, [f"ddpg.hidden={list(hidden)}", f"ddpg.symmetric_actor={str(symmetric).lower()}"]
        )
    metas = [SCRIPTED, _row_meta(path.resolve(), meta, run_dir and Path(run_dir).resolve())]
    kw = dict(cases=cases, seed=seed, max_steps=max_steps, traced=0)
    out, _, info = evaluate_policies(cfg, [None, params], [1, int(meta.get("k", 1))], **kw)
    result = _result(cfg, out, info, metas, seed, max_steps)
    eval_dir = RunDir(run_dir).eval if run_dir else path.parent / "eval"
    _write(eval_dir, f"{path.parent.name}_{path.stem}", result, cfg)
    return result


def _result(
    cfg: config.Config,
    out: dict[str, np.ndarray],
    info: CaseInfo,
    metas: list[Policy],
    seed: int,
    max_steps: int,
) -> EvalResult:
    """The content of eval.json: the setting, the cases, one row per policy."""
    # The run up to the gap is the same for every policy, so these counts are the cases'.
    early = out["reason"][0][~info.performed]
    box = (cfg.env.success_offset, cfg.env.success_heading, cfg.env.success_yaw_rate)
    return EvalResult(
        cfg.hash(),
        int(info.case.size),
        seed,
        max_steps,
        int(info.performed.sum()),
        int((info.side > 0).sum()),
        int((info.side < 0).sum()),
        {name: int((early == code).sum()) for code, name in enumerate(OUTCOMES)},
        info.traced.tolist(),
        dict(zip(("offset_m", "heading", "yaw_rate"), box, strict=True)),
        summarise(out, cfg.env.dt, cfg.env.reward_terms, metas),
    )


def _write(out_dir: Path, name: str, result: EvalResult, cfg: config.Config) -> None:
    write(out_dir / f"{name}.json", result)
    write_csv(out_dir / f"{name}.csv", result.rows, eval_fields(cfg.env.reward_terms))


def _policy_ids(metas: list[Policy]) -> dict[str, np.ndarray]:
    """Which model and episode each evaluated row is (-1 and 0 for the scripted baseline)."""
    return {
        "policy_model": np.asarray([-1 if m.model is None else m.model for m in metas]),
        "policy_episode": np.asarray([m.episode or 0 for m in metas]),
    }


def write_seed_stats(out_dir: Path, rows: list[Row]) -> stats.SeedStats:
    """``cells.json`` (everything), ``cells.csv`` (per cell and checkpoint) and
    ``improvement.csv`` (P(X > Y) of the final success rate) from eval rows; returns the
    JSON's content."""
    cells = stats.cells_of(rows)
    doc = stats.SeedStats(
        stats.CONFIDENCE,
        stats.RESAMPLES,
        stats.seeds_note(cells),
        stats.cell_table(cells),
        stats.final_table(cells),
        stats.improvement_table(cells),
    )
    write(out_dir / "cells.json", doc)
    write_csv(out_dir / "cells.csv", doc.cells)
    write_csv(out_dir / "improvement.csv", doc.improvement)
    return doc
