"""Drive jaxlc's lane changes with an exported policy: onnxruntime alone chooses the actions.

    python -m jaxlc.export runs/default --model ④ --out policy.onnx
    python examples/drive_onnx.py runs/default policy.onnx --lane-changes 1000

The simulator is jaxlc's gymnasium vector env (``jaxlc.gym.LaneChangeVectorEnv``), built from
the run's config with the policy's action-update step ``k`` (from ``policy.onnx.json``); each
of ``--lane-changes`` sub-envs, seeded ``--seed``, ``--seed + 1``, ..., drives its first lane
change, a stream of seeds apart from training's keys. The same lane changes are then driven
by ``jaxlc.policy.load_policy`` on the checkpoint the export names, and both success counts are
printed; the exit status is 1 when they differ. Needs ``pip install -e ".[export]"``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnxruntime as ort

from jaxlc.gym import LaneChangeVectorEnv
from jaxlc.policy import load_policy
from jaxlc.study.rundir import RunDir


def drive(
    policy: Callable[[np.ndarray], np.ndarray],
    run_dir: Path,
    k: int,
    lane_changes: int,
    seed: int,
) -> tuple[np.ndarray, np.ndarray]:
    """``(reasons, observations)``: each sub-env's first lane change's end (``(lane_changes,)``
    reason names) and every observation the policy was given (``(n, OBS_DIM)``)."""
    env = LaneChangeVectorEnv(lane_changes, config=RunDir(run_dir).load_config(), k=k)
    obs, _ = env.reset(seed=seed)
    reason = np.full(lane_changes, "", dtype=object)
    seen = []
    while (reason == "").any():
        seen.append(obs)
        obs, _, terminated, truncated, info = env.step(policy(obs))
        first = (terminated | truncated) & (reason == "")
        reason[first] = info["reason"][first]
    return reason, np.concatenate(seen)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path, help="the run the policy was exported from")
    ap.add_argument("policy", type=Path, help="policy.onnx written by python -m jaxlc.export")
    ap.add_argument("--lane-changes", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=1_000_000)
    args = ap.parse_args(argv)
    side = json.loads(args.policy.with_name(args.policy.name + ".json").read_text())
    session = ort.InferenceSession(str(args.policy), providers=["CPUExecutionProvider"])

    def onnx_policy(obs: np.ndarray) -> np.ndarray:
        return session.run(["action"], {"obs": np.asarray(obs, np.float32)})[0]

    act, _ = load_policy(args.run_dir / side["checkpoint"])

    def jax_policy(obs: np.ndarray) -> np.ndarray:
        return np.asarray(act(obs))

    k, n = side["output"]["k"], args.lane_changes
    counts = {}
    for name, policy in (("onnxruntime", onnx_policy), ("load_policy", jax_policy)):
        reasons, _ = drive(policy, args.run_dir, k, n, args.seed)
        counts[name] = int((reasons == "success").sum())
        print(
            f"{name:12} {side['label']} episode {side['episode']}: {counts[name]} of {n} "
            f"lane changes succeed ({100 * counts[name] / n:.1f}%)"
        )
    return 0 if len(set(counts.values())) == 1 else 1


if __name__ == "__main__":
    sys.exit(main())
