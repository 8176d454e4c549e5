"""README's curved-road picture: frames of one scripted lane change on a curved road, drawn by
the gymnasium env's ``render()`` (``jaxlc.gym.render_frame``), stacked into one PNG.

    python benchmarks/scripts/curved_frame.py --curvature 0.004 --seed 1 --out docs/curved_road.png

The controller is ``jaxlc.sim.controller.scripted_action`` (pole placement with curvature
feed-forward); the frames are taken every ``--every`` RL steps from the manoeuvre's start.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

from jaxlc import config
from jaxlc.gym import LaneChangeGymEnv
from jaxlc.sim.controller import scripted_action


def frames(curvature: float, seed: int, every: int, count: int) -> tuple[list[np.ndarray], str]:
    cfg = config.load(None, [f"env.curvature={curvature!r}"])  # validated: a bad κ names itself
    env = LaneChangeGymEnv(config=cfg, render_mode="rgb_array")
    obs, _ = env.reset(seed=seed)
    shots, reason = [env.render()], "running"
    for t in range(1, every * (count - 1) + 1):
        action = np.asarray(scripted_action(jnp.asarray(obs), env.params))
        obs, _, term, trunc, info = env.step(action)
        if t % every == 0 or term or trunc:
            shots.append(env.render())
        if term or trunc:
            reason = info["reason"]
            break
    return shots, reason


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--curvature", type=float, default=0.004, help="1/m, the road's constant κ")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--every", type=int, default=12, help="RL steps between frames")
    ap.add_argument("--count", type=int, default=4, help="frames at most")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    shots, reason = frames(args.curvature, args.seed, args.every, args.count)
    gap = np.full((6, shots[0].shape[1], 3), 255, np.uint8)
    picture = np.concatenate([x for shot in shots for x in (shot, gap)][:-1])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    plt.imsave(args.out, picture)
    print(f"{args.out}: {len(shots)} frames, κ = {args.curvature} 1/m, the lane change: {reason}")


if __name__ == "__main__":
    main()
