"""``python -m jaxlc.export RUN_DIR``: a trained actor as one ONNX graph (or StableHLO), for use
outside JAX.

    python -m jaxlc.export runs/default --model ④ --out policy.onnx
    python -m jaxlc.export runs/default --model 3 --episode 4000 --out policy.onnx
    python -m jaxlc.export runs/default --format stablehlo --out policy.stablehlo

The graph computes exactly what ``jaxlc.policy.load_policy``'s ``act`` computes: from the
observation vector as the env returns it, ``(batch, OBS_DIM)`` float32 already scaled, to the
action ``(batch, 1)`` in [-1, 1] (``(batch, 2)`` with ``env.longitudinal = "policy"``, each
entry named in the JSON; the reflection-odd structure included where the actor has it);
nothing is left in Python beside it. It is converted from that same function (jax2onnx),
so the two cannot drift apart, and checked by ``tests/test_export.py`` against onnxruntime.
``--format stablehlo`` writes ``jax.export``'s serialisation instead (for JAX consumers:
``jax.export.deserialize(bytes).call(obs)``).

Beside it, ``OUT.json``: the observation layout (name, scale, meaning and sign under the road's
reflection of every entry, in order), the action's meaning, bound and scale to the physical
yaw acceleration, ``k`` (the action is held for k steps of ``dt``), the checkpoint, its episode,
the config hash and the jaxlc version. Needs the ``export`` extra: ``pip install -e
".[export]"`` (part of ``dev``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from jaxlc.policy import load_policy, onnx_model, sidecar, stablehlo_bytes
from jaxlc.study import checkpoint
from jaxlc.study.checkpoint import write_bytes_atomic, write_text_atomic
from jaxlc.study.rundir import RunDir

FORMATS = ("onnx", "stablehlo")


class ExportError(Exception):
    """A run directory, model or episode that cannot be exported; one line for the user."""


def _choices(found: list[tuple[Path, dict[str, Any]]]) -> str:
    models = sorted({(m["model"], m.get("seed"), m.get("label")) for _, m in found})
    return ", ".join(f"{i} ({label}, seed {seed})" for i, seed, label in models)


def pick_checkpoint(
    run_dir: Path, model: str | None = None, episode: int | None = None
) -> tuple[Path, dict[str, Any]]:
    """The checkpoint of ``model`` (its index, its label, or the label's first word such as
    ``④``; default model 0) at ``episode`` (default its last). Raises ``ExportError`` naming
    what is missing and the choices (``CheckpointError`` where the run has no checkpoints:
    ``RunDir.saved_checkpoints``)."""
    found = RunDir(run_dir).saved_checkpoints()
    want = "0" if model is None else model.strip()
    if want.isascii() and want.isdecimal():  # an index; "④".isdigit() is True in Python
        mine = [(p, m) for p, m in found if m["model"] == int(want)]
    else:
        label = [(p, m) for p, m in found if want in (m["label"], m["label"].split(" ")[0])]
        mine = label or [(p, m) for p, m in found if m["label"].endswith(want)]
    if not mine:
        raise ExportError(f"no model '{want}' in {run_dir}; the models: {_choices(found)}")
    if len({m["model"] for _, m in mine}) > 1:
        raise ExportError(
            f"'{want}' names several models (one per seed); give the index: {_choices(mine)}"
        )
    if episode is None:
        return max(mine, key=lambda pm: pm[1]["episode"])
    at = [(p, m) for p, m in mine if m["episode"] == episode]
    if not at:
        saved = ", ".join(
            str(m["episode"]) for _, m in sorted(mine, key=lambda pm: pm[1]["episode"])
        )
        raise ExportError(
            f"model {mine[0][1]['model']} has no checkpoint at episode {episode}; saved: {saved}"
        )
    return at[0]


def export(
    run_dir: Path,
    out: Path,
    model: str | None = None,
    episode: int | None = None,
    fmt: str = "onnx",
) -> tuple[Path, Path]:
    """Write the chosen checkpoint's actor to ``out`` and its sidecar to ``out + .json``."""
    path, meta = pick_checkpoint(run_dir, model, episode)
    act, _ = load_policy(path)
    # the params as constants of the graph, in float32 as the actor runs them
    data = stablehlo_bytes(act) if fmt == "stablehlo" else onnx_model(act).SerializeToString()
    write_bytes_atomic(out, data)
    side = out.with_name(out.name + ".json")
    write_text_atomic(side, json.dumps(sidecar(path, meta, run_dir, fmt), indent=1))
    return out, side


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m jaxlc.export",
        description=__doc__.splitlines()[0],
        epilog="Writes OUT and OUT.json; exit status 2 names what is missing.",
    )
    ap.add_argument("run_dir", type=Path, help="run directory of jaxlc.sweep")
    ap.add_argument("--model", help="model index or label (e.g. 3, ④, 'k=1 D=4000'); default 0")
    ap.add_argument("--episode", type=int, help="checkpoint episode (default: the model's last)")
    ap.add_argument("--format", choices=FORMATS, default="onnx")
    ap.add_argument(
        "--out",
        type=Path,
        help="file to write (default: policy.onnx, or policy.stablehlo with --format stablehlo)",
    )
    args = ap.parse_args(argv)
    args.out = args.out or Path(f"policy.{args.format}")
    try:
        out, side = export(args.run_dir, args.out, args.model, args.episode, args.format)
    except (ExportError, checkpoint.CheckpointError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except ImportError as err:
        print(f'error: {err.name} is missing: pip install -e ".[export]"', file=sys.stderr)
        return 2
    doc = json.loads(side.read_text())
    print(f"Wrote {out} ({doc['label']}, seed {doc['seed']}, episode {doc['episode']}) and {side}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
