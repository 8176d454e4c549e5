"""Checkpoint round trip, rejection of damaged/incompatible files, atomic writes, listing."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxlc.study import checkpoint
from jaxlc.study.checkpoint import CheckpointError


def _params(obs: int = 17) -> dict:
    rng = np.random.default_rng(0)
    return {
        "actor": {
            "Dense_0": {
                "kernel": rng.standard_normal((obs, 300)).astype(np.float32),
                "bias": np.zeros(300, np.float32),
            },
            "Dense_1": {"kernel": jnp.ones((300, 1), jnp.bfloat16), "bias": jnp.zeros(1)},
        },
        "critic": {"Dense_0": {"kernel": rng.standard_normal((obs + 1, 4)).astype(np.float64)}},
        "step": np.array(7, np.int32),
    }


def _meta(model: str = "k1_m2000", seed: int = 0, episode: int = 100) -> dict:
    return {"model": model, "seed": seed, "episode": episode, "config_hash": "abc123"}


@pytest.fixture
def saved(tmp_path: Path) -> Path:
    return checkpoint.save(tmp_path / "ck.msgpack", _params(), _meta())


@pytest.mark.parametrize("suffix", [".msgpack", ".json"])
def test_round_trip_is_identical(saved: Path, suffix: str) -> None:
    params = _params()
    loaded, meta = checkpoint.load(saved.with_suffix(suffix))
    assert jax.tree.structure(loaded) == jax.tree.structure(params)
    for want, got in zip(jax.tree.leaves(params), jax.tree.leaves(loaded), strict=True):
        assert isinstance(got, np.ndarray)
        assert got.dtype == np.asarray(want).dtype
        np.testing.assert_array_equal(got, np.asarray(want))
    assert {k: meta[k] for k in _meta()} == _meta()
    assert meta["shapes"] == checkpoint.shapes_of(params)
    assert meta["shapes"]["actor/Dense_0/kernel"] == [17, 300]
    assert meta["shapes"]["step"] == []
    assert meta["jaxlc_version"] == checkpoint._jaxlc_version()


def test_numpy_scalars_in_meta_are_saved_as_json_numbers(tmp_path: Path) -> None:
    path = checkpoint.save(tmp_path / "ck.msgpack", _params(), {"episode": np.int64(3)})
    assert json.loads(path.with_suffix(".json").read_text())["episode"] == 3


def test_bad_meta_writes_nothing(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="cannot save checkpoint"):
        checkpoint.save(tmp_path / "ck.msgpack", _params(), {"bad": object()})
    assert list(tmp_path.iterdir()) == []


def test_truncated_msgpack_is_rejected(saved: Path) -> None:
    data = saved.read_bytes()
    saved.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match=r"ck\.msgpack is truncated or corrupt"):
        checkpoint.load(saved)


@pytest.mark.parametrize(
    "garbage",
    [
        b"this is not msgpack at all \x00\xff\xfe" * 10,
        b"\x01",  # valid msgpack (the int 1), not a params tree
        json.dumps({"a": 1}).encode(),
    ],
    ids=["bytes", "int", "json"],
)
def test_garbage_msgpack_is_rejected(saved: Path, garbage: bytes) -> None:
    saved.write_bytes(garbage)
    with pytest.raises(CheckpointError, match="is truncated or corrupt"):
        checkpoint.load(saved)


def test_params_that_disagree_with_their_json_are_rejected(saved: Path, tmp_path: Path) -> None:
    # A well-formed msgpack of another tree: only the shape check against the JSON catches it.
    other = checkpoint.save(tmp_path / "other.msgpack", _params(obs=5), _meta())
    saved.write_bytes(other.read_bytes())
    with pytest.raises(CheckpointError, match="truncated or corrupt.*do not match its JSON"):
        checkpoint.load(saved)


def test_garbage_json_is_rejected(saved: Path) -> None:
    saved.with_suffix(".json").write_text("{not json")
    with pytest.raises(CheckpointError, match="truncated or corrupt"):
        checkpoint.load(saved)


def test_other_version_is_rejected(saved: Path) -> None:
    json_path = saved.with_suffix(".json")
    meta = json.loads(json_path.read_text())
    meta["jaxlc_version"] = "9.9.1"
    json_path.write_text(json.dumps(meta))
    running = ".".join(checkpoint._jaxlc_version().split(".")[:2])
    msg = f"was written by jaxlc 9.9, this is {running}; re-run the sweep or install jaxlc==9.9"
    with pytest.raises(CheckpointError, match=msg.replace(".", r"\.")):
        checkpoint.load(saved)


def test_other_patch_version_loads(saved: Path) -> None:
    json_path = saved.with_suffix(".json")
    meta = json.loads(json_path.read_text())
    major, minor = checkpoint._jaxlc_version().split(".")[:2]
    meta["jaxlc_version"] = f"{major}.{minor}.99"
    json_path.write_text(json.dumps(meta))
    checkpoint.load(saved)


def test_expected_shapes_match(saved: Path) -> None:
    checkpoint.load(saved, expect_shapes=checkpoint.shapes_of(_params()))


def test_other_network_shape_is_rejected(saved: Path) -> None:
    expect = checkpoint.shapes_of(_params(obs=14))
    msg = (
        f"checkpoint {saved} has a network of another shape: "
        "actor/Dense_0/kernel is (17, 300), expected (14, 300)"
    )
    with pytest.raises(CheckpointError) as info:
        checkpoint.load(saved, expect_shapes=expect)
    assert str(info.value).startswith(msg)
    assert "\n" not in str(info.value)


def test_missing_leaf_is_rejected(saved: Path) -> None:
    expect = {**checkpoint.shapes_of(_params()), "actor/Dense_2/kernel": (300, 1)}
    with pytest.raises(CheckpointError, match="has no leaf actor/Dense_2/kernel"):
        checkpoint.load(saved, expect_shapes=expect)


def test_missing_checkpoint_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="does not exist"):
        checkpoint.load(tmp_path / "nope.msgpack")


def test_checkpoint_without_json_is_incomplete(saved: Path) -> None:
    saved.with_suffix(".json").unlink()
    with pytest.raises(CheckpointError, match="is incomplete"):
        checkpoint.load(saved)


def _chmod_blocks_writes(directory: Path) -> bool:
    probe = directory / "probe"
    try:
        probe.write_bytes(b"")
    except PermissionError:
        return True
    probe.unlink()
    return False  # root (or a file system that ignores modes)


def _fail(err: int):
    def raise_oserror(*args, **kwargs):
        raise OSError(err, os.strerror(err))

    return raise_oserror


@pytest.mark.parametrize("failure", ["unwritable_dir", "enospc_on_fsync", "enospc_on_replace"])
def test_failed_atomic_write_keeps_previous_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, failure: str
) -> None:
    directory = tmp_path / "out"
    directory.mkdir()
    target = directory / "ck.msgpack"
    target.write_bytes(b"previous contents")
    reason = os.strerror(errno.ENOSPC)
    if failure == "unwritable_dir":
        directory.chmod(0o500)
        if _chmod_blocks_writes(directory):
            reason = os.strerror(errno.EACCES)
        else:  # running as root: chmod does not stop writes, so simulate a full disk
            monkeypatch.setattr(checkpoint.os, "replace", _fail(errno.ENOSPC))
    elif failure == "enospc_on_fsync":
        monkeypatch.setattr(checkpoint.os, "fsync", _fail(errno.ENOSPC))
    else:
        monkeypatch.setattr(checkpoint.os, "replace", _fail(errno.ENOSPC))
    try:
        with pytest.raises(CheckpointError) as info:
            checkpoint.write_bytes_atomic(target, b"new contents " * 1000)
    finally:
        directory.chmod(0o700)
    msg = str(info.value)
    assert str(target) in msg and reason in msg and "\n" not in msg
    assert target.read_bytes() == b"previous contents"
    assert [p.name for p in directory.iterdir()] == ["ck.msgpack"]


def test_atomic_write_replaces_file(tmp_path: Path) -> None:
    target = tmp_path / "meta.json"
    target.write_text("old")
    checkpoint.write_text_atomic(target, "new ✓")
    assert target.read_text(encoding="utf-8") == "new ✓"
    assert [p.name for p in tmp_path.iterdir()] == ["meta.json"]


def test_list_checkpoints_sorts_complete_ones(tmp_path: Path) -> None:
    ck = tmp_path / "checkpoints"
    order = [("a", 0, 100), ("a", 0, 200), ("a", 1, 100), ("b", 0, 50), ("b", 0, 1000)]
    for i, (model, seed, episode) in enumerate(reversed(order)):
        checkpoint.save(ck / f"x{i}.msgpack", {"w": np.zeros(2)}, _meta(model, seed, episode))
    (ck / "orphan.msgpack").write_bytes(b"save interrupted before its JSON")
    (ck / "notes.json").write_text('{"not": "a checkpoint"}')
    checkpoint.save(ck / "lost.msgpack", {"w": np.zeros(2)}, _meta()).unlink()
    found = checkpoint.list_checkpoints(tmp_path)
    assert {p.name for p in found}.isdisjoint({"orphan.msgpack", "lost.msgpack"})
    assert all(p.suffix == ".msgpack" for p in found)
    got = [tuple(checkpoint.load(p)[1][k] for k in ("model", "seed", "episode")) for p in found]
    assert got == order


def test_list_checkpoints_of_empty_run(tmp_path: Path) -> None:
    assert checkpoint.list_checkpoints(tmp_path) == []


def test_resave_over_existing_checkpoint(saved: Path) -> None:
    checkpoint.save(saved, _params(obs=5), _meta(episode=200))
    params, meta = checkpoint.load(saved, expect_shapes=checkpoint.shapes_of(_params(obs=5)))
    assert meta["episode"] == 200
    assert params["actor"]["Dense_0"]["kernel"].shape == (5, 300)


def test_interrupted_resave_is_incomplete_not_mismatched(
    saved: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The JSON write fails after the new params landed: the old JSON must not vouch for them.
    def disk_full(path, text):
        raise CheckpointError(f"cannot write {path}: No space left on device")

    monkeypatch.setattr(checkpoint, "write_text_atomic", disk_full)
    with pytest.raises(CheckpointError):
        checkpoint.save(saved, _params(), _meta(episode=200))
    with pytest.raises(CheckpointError, match="is incomplete"):
        checkpoint.load(saved)
    assert checkpoint.list_checkpoints(saved.parent) == []


def test_a_run_written_before_a_key_keeps_the_behaviour_it_had(tmp_path):
    """A resolved config spells every key; one without ``symmetric_actor``, ``mirror_pairs`` or
    ``gap_min_ttc`` ran with a plain actor, rows reflected at random and no time-to-collision
    test, whatever today's defaults are."""
    from jaxlc import config
    from jaxlc.study.rundir import RunDir

    today = config.Config()
    d = today.ddpg
    assert d.symmetric_actor and d.mirror_pairs and today.env.gap_min_ttc > 0  # else no test
    run = RunDir(tmp_path)
    run.write_config(today)
    assert run.load_config() == today
    lines = run.config.read_text().splitlines()
    keys = ("symmetric_actor", "mirror_pairs", "gap_min_ttc")
    old = [x for x in lines if not x.startswith(keys)]
    assert len(old) == len(lines) - 3
    run.config.write_text("\n".join(old) + "\n")
    cfg = run.load_config()
    assert not cfg.ddpg.symmetric_actor and cfg.env.gap_min_ttc == 0.0
    assert not cfg.ddpg.mirror_pairs
    assert cfg.ddpg.hidden == today.ddpg.hidden and cfg.train == today.train
