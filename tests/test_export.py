"""A trained actor out of JAX: the ONNX graph and the StableHLO export compute what
``load_policy`` computes, on observations from real rollouts and on the layout's edges."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxlc import export, policy
from jaxlc.policy import actor_fn, load_policy
from jaxlc.sim.env import OBS_DIM, make
from jaxlc.sim.observation import INDEX, MIRROR_SIGNS, bounds
from jaxlc.study import checkpoint

ort = pytest.importorskip("onnxruntime", reason="the export extra: pip install -e '.[export]'")
pytest.importorskip("jax2onnx", reason="the export extra: pip install -e '.[export]'")

TOL = 1e-5  # absolute, on actions in [-1, 1]
EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "drive_onnx.py"


def _example():
    spec = importlib.util.spec_from_file_location("drive_onnx", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _session(path: Path):
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def _run(session, obs: np.ndarray) -> np.ndarray:
    return session.run(["action"], {"obs": np.asarray(obs, np.float32)})[0]


def _edges(rng: np.random.Generator) -> np.ndarray:
    """The layout's edges: both bounds, zeros, empty lanes (gap sentinels, dv 0), and draws
    across the bounds, each with its reflection."""
    low, high = bounds(make()[1])
    empty = np.zeros(OBS_DIM, np.float32)
    for gap in ("lead_gap", "lag_gap", "own_gap"):
        empty[INDEX[gap]] = 1.0  # the 100 m of a missing vehicle, scaled
    drawn = rng.uniform(low, high, (2000, OBS_DIM)).astype(np.float32)
    rows = np.concatenate([np.stack([low, high, np.zeros(OBS_DIM), empty]), drawn])
    rows = rows.astype(np.float32)
    return np.concatenate([rows, rows * np.asarray(MIRROR_SIGNS, np.float32)])


@pytest.fixture(scope="module")
def exported(smoke_run, tmp_path_factory) -> tuple[Path, Path, dict]:
    run_dir, _ = smoke_run
    out = tmp_path_factory.mktemp("export") / "policy.onnx"
    assert export.main([str(run_dir), "--model", "0", "--out", str(out)]) == 0
    return run_dir, out, json.loads(out.with_name("policy.onnx.json").read_text())


@pytest.fixture(scope="module")
def rollout(exported) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Both policies driving the same 100 lane changes; the observations load_policy saw."""
    run_dir, path, side = exported
    drive, session = _example().drive, _session(path)
    act, _ = load_policy(run_dir / side["checkpoint"])
    k = side["output"]["k"]
    by_onnx, _ = drive(lambda o: _run(session, o), run_dir, k, 100, 1_000_000)
    by_jax, seen = drive(lambda o: np.asarray(act(o)), run_dir, k, 100, 1_000_000)
    return by_onnx, by_jax, seen


def test_onnx_actions_equal_load_policy_on_rollouts_and_edges(exported, rollout) -> None:
    run_dir, path, side = exported
    act, _ = load_policy(run_dir / side["checkpoint"])
    _, _, seen = rollout
    # the smoke actor (40 episodes) leaves the road within some 10-20 steps of each of its
    # 100 lane changes: about a thousand rollout observations, with their reflections and
    # the layout's 4,008 edge rows beside them
    assert seen.shape[0] >= 500 and np.isfinite(seen).all()
    obs = np.concatenate([seen, seen * np.asarray(MIRROR_SIGNS, np.float32)])
    obs = np.concatenate([obs, _edges(np.random.default_rng(0))])
    got, want = _run(_session(path), obs), np.asarray(act(obs))
    assert got.shape == want.shape == (obs.shape[0], 1)
    np.testing.assert_allclose(got, want, rtol=0, atol=TOL)
    # the smoke actor is reflection-odd, and so is the graph: mu(Ms) = -mu(s)
    assert side["symmetric_actor"]
    mirrored = _run(_session(path), seen * np.asarray(MIRROR_SIGNS, np.float32))
    np.testing.assert_allclose(mirrored, -_run(_session(path), seen), rtol=0, atol=1e-6)


def test_a_plain_actor_and_stablehlo_export_alike(exported, tmp_path) -> None:
    run_dir, _, side = exported
    params, meta = checkpoint.load(run_dir / side["checkpoint"])
    obs = _edges(np.random.default_rng(1))
    plain = actor_fn(params, meta["hidden"], symmetric=False)
    model = policy.onnx_model(plain)
    (tmp_path / "plain.onnx").write_bytes(model.SerializeToString())
    got = _run(_session(tmp_path / "plain.onnx"), obs)
    np.testing.assert_allclose(got, np.asarray(plain(obs)), rtol=0, atol=TOL)
    out = tmp_path / "policy.stablehlo"
    assert export.main([str(run_dir), "--format", "stablehlo", "--out", str(out)]) == 0
    call = jax.export.deserialize(bytearray(out.read_bytes())).call
    act, _ = load_policy(run_dir / side["checkpoint"])
    np.testing.assert_allclose(np.asarray(call(obs)), np.asarray(act(obs)), rtol=0, atol=TOL)


def test_onnx_drives_the_same_lane_changes_to_the_same_ends(rollout) -> None:
    by_onnx, by_jax, _ = rollout
    assert (by_onnx != "").all()
    assert (by_onnx == by_jax).all()


def test_the_sidecar_says_what_the_graph_takes_and_gives(exported) -> None:
    run_dir, _, side = exported
    layout = side["input"]["layout"]
    assert [e["index"] for e in layout] == list(range(OBS_DIM))
    assert [e["mirror_sign"] for e in layout] == list(MIRROR_SIGNS)
    assert side["output"]["bound"] == [-1.0, 1.0]
    assert side["output"]["scale"] == make()[1].max_yaw_acc  # rad/s^2 at action 1
    meta = json.loads((run_dir / side["checkpoint"]).with_suffix(".json").read_text())
    assert (side["episode"], side["config_hash"], side["output"]["k"]) == (
        meta["episode"],
        meta["config_hash"],
        meta["k"],
    )


@pytest.mark.parametrize(
    "args, says",
    [
        (["--model", "99"], "no model '99'"),
        (["--episode", "7"], "no checkpoint at episode 7; saved:"),
        (["--model", "k=9 D=1"], "the models: 0 ("),
        (["--model", "④"], "no model '④'"),  # a paper tag the smoke grid lacks
    ],
)
def test_bad_input_is_one_line_exit_2(exported, tmp_path, capsys, args, says) -> None:
    run_dir, _, _ = exported
    assert export.main([str(run_dir), *args, "--out", str(tmp_path / "x.onnx")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err, err
    assert not (tmp_path / "x.onnx").exists()


def test_a_run_without_checkpoints_is_refused(tmp_path, capsys) -> None:
    assert export.main([str(tmp_path), "--out", str(tmp_path / "x.onnx")]) == 2
    assert "no checkpoints in" in capsys.readouterr().err
