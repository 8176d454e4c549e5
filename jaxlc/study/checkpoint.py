"""Checkpoints: a params pytree as ``NAME.msgpack`` plus a sidecar ``NAME.json`` of metadata.

The msgpack is written first and the JSON last, both atomically, so a checkpoint is complete
exactly when its JSON exists; a crash mid-save leaves at most an orphan msgpack, which
``list_checkpoints`` ignores. The JSON records the jaxlc version and the shape of every leaf,
so a loader can reject an incompatible or damaged checkpoint without the config.
"""

from __future__ import annotations

import contextlib
import errno
import importlib.metadata
import json
import os
import secrets
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from flax import serialization, traverse_util

__all__ = [
    "TRAIN_STATE_FILE",
    "CheckpointError",
    "WriteError",
    "list_checkpoints",
    "load",
    "save",
    "shapes_of",
    "write_bytes_atomic",
    "write_text_atomic",
]


# A sweep's full training state (``RUN_DIR/state/``): not a checkpoint, read by --resume.
TRAIN_STATE_FILE = "train_state.msgpack"
CHECKPOINTS_DIR = "checkpoints"  # under a run directory


class CheckpointError(Exception):
    """A checkpoint cannot be written or read; the message names the problem and the fix."""


class WriteError(CheckpointError):
    """A file could not be written; ``remedy`` says what the user must do about the disk,
    so a caller that knows what comes next (the sweep: ``--resume``) can say the rest."""

    def __init__(self, path: Path, reason: str, remedy: str) -> None:
        self.path, self.reason, self.remedy = path, reason, remedy
        super().__init__(f"cannot write {path}: {reason}; {remedy} and save again")


# --------------------------------------------------------------------------- atomic writes

_REMEDIES = {
    errno.ENOSPC: "free some disk space",
    errno.EDQUOT: "free some disk quota",
    errno.EACCES: "make the directory writable or choose another output directory",
    errno.EPERM: "make the directory writable or choose another output directory",
    errno.EROFS: "choose an output directory on a writable file system",
    errno.ENOENT: "create the directory or choose another output directory",
}


def _write_error(path: Path, err: OSError) -> WriteError:
    remedy = _REMEDIES.get(err.errno or 0, "check the output directory")
    return WriteError(path, err.strerror or str(err), remedy)


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` so readers see the old file or the new one, never a part."""
    path = Path(path)
    # Same directory as the target, so os.replace is a rename within one file system.
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    created = False
    try:
        # os.open with 0o666 honours the umask (mkstemp would force 0o600 on the result).
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
        fd = os.open(tmp, flags, 0o666)
        created = True
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        if created:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        raise _write_error(path, err) from err
    _fsync_dir(path.parent)
    return path


def write_text_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """``write_bytes_atomic`` of ``text`` encoded as UTF-8."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def _fsync_dir(directory: Path) -> None:
    # Makes the rename itself durable; best effort, as some platforms cannot open directories.
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# --------------------------------------------------------------------------- versions, shapes


def _jaxlc_version() -> str:
    import jaxlc  # deferred: jaxlc/__init__ may import this module

    version = getattr(jaxlc, "__version__", None)
    if version:
        return str(version)
    try:
        return importlib.metadata.version("jaxlc")
    except importlib.metadata.PackageNotFoundError:
        return "0.1.0"  # running from a source tree that was never installed


def _major_minor(version: str) -> str:
    return ".".join(version.split(".")[:2])


def shapes_of(params: Any) -> dict[str, list[int]]:
    """Shape of every leaf, keyed ``"a/b/c"`` by its path in the (state-dict form of) pytree."""
    # to_state_dict gives the keys a restored checkpoint has (e.g. list index i -> "i").
    state = serialization.to_state_dict(params)
    if not isinstance(state, Mapping):
        return {"": list(np.shape(state))}
    flat = traverse_util.flatten_dict(state, sep="/")
    return {str(k): [int(d) for d in np.shape(v)] for k, v in flat.items()}


def _fmt(shape: Any) -> str:
    return str(tuple(int(d) for d in shape))


def _first_difference(got: dict[str, list[int]], want: Mapping[str, Any]) -> str | None:
    for key, shape in want.items():
        if key not in got:
            return f"has no leaf {key}, expected {_fmt(shape)}"
        if list(got[key]) != [int(d) for d in shape]:
            return f"{key} is {_fmt(got[key])}, expected {_fmt(shape)}"
    for key, shape in got.items():
        if key not in want:
            return f"has an unexpected leaf {key} {_fmt(shape)}"
    return None


def _json_default(obj: Any) -> Any:
    # Episode counters and metrics often arrive as numpy/jax scalars straight from training.
    if isinstance(obj, np.generic):
        return obj.item()
    if hasattr(obj, "__array__"):
        return np.asarray(obj).tolist()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


# --------------------------------------------------------------------------- save / load


def _paths(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    path = Path(path)
    if path.suffix not in (".msgpack", ".json"):
        raise CheckpointError(
            f"checkpoint path {path} must end in .msgpack (or .json for its sidecar); "
            "rename it or pass the .msgpack file"
        )
    return path.with_suffix(".msgpack"), path.with_suffix(".json")


def save(path: str | os.PathLike[str], params: Any, meta: Mapping[str, Any]) -> Path:
    """Save ``params`` to ``path`` (``.msgpack``) and ``meta`` to its ``.json``; returns ``path``.

    The JSON holds ``meta`` plus ``"jaxlc_version"`` and ``"shapes"`` (see ``shapes_of``).
    """
    if Path(path).suffix != ".msgpack":
        raise CheckpointError(f"checkpoint path {path} must end in .msgpack; rename it")
    msgpack_path, json_path = _paths(path)
    record = {**meta, "jaxlc_version": _jaxlc_version(), "shapes": shapes_of(params)}
    try:
        # Serialise everything before touching the disk, so a bad meta writes nothing.
        text = json.dumps(record, indent=1, default=_json_default) + "\n"
        data = serialization.to_bytes(params)
    except (TypeError, ValueError) as err:
        raise CheckpointError(
            f"cannot save checkpoint {msgpack_path}: {err}; pass meta of plain JSON values "
            "and params as a pytree of arrays"
        ) from err
    try:
        msgpack_path.parent.mkdir(parents=True, exist_ok=True)
        # Overwriting: drop the old JSON first, else a failure between the two writes would
        # pair the new params with the old metadata and still look complete.
        json_path.unlink(missing_ok=True)
    except OSError as err:
        raise _write_error(json_path, err) from err
    write_bytes_atomic(msgpack_path, data)
    write_text_atomic(json_path, text)
    return msgpack_path


def _corrupt(path: Path, reason: str) -> CheckpointError:
    return CheckpointError(
        f"checkpoint {path} is truncated or corrupt: {reason}; delete it and use an earlier "
        "checkpoint or re-run the sweep"
    )


def _read_meta(msgpack_path: Path, json_path: Path) -> dict[str, Any]:
    if not json_path.exists():
        if msgpack_path.name == TRAIN_STATE_FILE:
            run_dir = msgpack_path.parent.parent
            raise CheckpointError(
                f"{msgpack_path} is a run's full training state, not a checkpoint: continue "
                f"the run with python -m jaxlc.sweep --resume {run_dir}, or load a policy from "
                f"{run_dir / 'checkpoints'}"
            )
        if msgpack_path.exists():
            raise CheckpointError(
                f"checkpoint {msgpack_path} is incomplete: {json_path.name} is missing, so its "
                "save was interrupted; use an earlier checkpoint or re-run the sweep"
            )
        raise CheckpointError(
            f"checkpoint {msgpack_path} does not exist; check the path "
            "(list_checkpoints(run_dir) shows the complete ones)"
        )
    try:
        meta = json.loads(json_path.read_text(encoding="utf-8"))
    except OSError as err:
        raise CheckpointError(
            f"cannot read {json_path}: {err.strerror or err}; check its permissions"
        ) from err
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise _corrupt(json_path, f"its JSON does not parse ({err})") from err
    if not isinstance(meta, dict) or not isinstance(meta.get("jaxlc_version"), str):
        raise _corrupt(json_path, "its JSON has no jaxlc_version")
    if not isinstance(meta.get("shapes"), dict):
        raise _corrupt(json_path, "its JSON has no leaf shapes")
    return meta


def load(
    path: str | os.PathLike[str], expect_shapes: Mapping[str, Any] | None = None
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Load a checkpoint (its ``.msgpack`` or ``.json`` path) -> ``(params, meta)``.

    ``params`` is a nested dict of numpy arrays; ``meta`` is the sidecar JSON as saved
    (including ``jaxlc_version`` and ``shapes``). Raises ``CheckpointError`` for a missing,
    incomplete, corrupt, other-version or (given ``expect_shapes``) other-shape checkpoint.
    """
    msgpack_path, json_path = _paths(path)
    meta = _read_meta(msgpack_path, json_path)

    saved, running = _major_minor(meta["jaxlc_version"]), _major_minor(_jaxlc_version())
    if saved != running:
        raise CheckpointError(
            f"checkpoint {msgpack_path} was written by jaxlc {saved}, this is {running}; "
            f"re-run the sweep or install jaxlc=={saved}"
        )

    try:
        data = msgpack_path.read_bytes()
    except FileNotFoundError as err:
        raise CheckpointError(
            f"checkpoint {msgpack_path} is missing its params file though {json_path.name} "
            "exists; use an earlier checkpoint or re-run the sweep"
        ) from err
    except OSError as err:
        raise CheckpointError(
            f"cannot read {msgpack_path}: {err.strerror or err}; check its permissions"
        ) from err
    try:
        params = serialization.msgpack_restore(data)
    except Exception as err:  # msgpack raises many unrelated types on arbitrary bytes
        raise _corrupt(msgpack_path, f"msgpack decoding failed ({err})") from err
    if not isinstance(params, dict):
        raise _corrupt(msgpack_path, f"it holds a {type(params).__name__}, not a params tree")

    got = shapes_of(params)
    diff = _first_difference(got, meta["shapes"])
    if diff is not None:
        raise _corrupt(msgpack_path, f"its params do not match its JSON: {diff}")
    if expect_shapes is not None:
        diff = _first_difference(got, expect_shapes)
        if diff is not None:
            raise CheckpointError(
                f"checkpoint {msgpack_path} has a network of another shape: {diff}; load it "
                "with the config it was trained with"
            )
    return params, meta


# --------------------------------------------------------------------------- listing


def _order(value: Any) -> tuple[int, Any]:
    # Numbers sort numerically and before strings; a missing key sorts last.
    if isinstance(value, int | float) and not isinstance(value, bool):
        return (0, value)
    if value is None:
        return (2, "")
    return (1, str(value))


def list_checkpoints(run_dir: str | os.PathLike[str]) -> list[Path]:
    """Complete checkpoints (``.msgpack`` paths whose JSON exists) under ``run_dir/checkpoints``.

    Sorted by the ``model``, ``seed`` and ``episode`` recorded in each JSON.
    """
    root = Path(run_dir) / CHECKPOINTS_DIR
    found = []
    for json_path in root.rglob("*.json"):
        msgpack_path = json_path.with_suffix(".msgpack")
        if not msgpack_path.is_file():
            continue
        try:
            meta = json.loads(json_path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            meta = None
        if not isinstance(meta, dict) or "jaxlc_version" not in meta:
            continue  # not a sidecar written by save(); the sidecar is written atomically
        key = tuple(_order(meta.get(k)) for k in ("model", "seed", "episode"))
        found.append((key, str(msgpack_path), msgpack_path))
    return [p for *_, p in sorted(found)]
