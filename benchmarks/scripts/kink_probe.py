"""Does a stalled policy sit at a maximum of the true return? Branch rollouts from the
states where a checkpoint's lane changes stall.

A policy that stops short of the target lane and times out may sit where the critic's
Q(s*, .) peaks at its own action: the |omega| and |a_lat| penalties are linear in the action,
so one push toward the lane centre can cost more at once than it gains. This probe asks the
simulator instead of the critic. It drives ``--envs`` envs with the checkpoint's policy (no
noise) and captures each env's state once its manoeuvre has run ``--at`` seconds (stalled:
the policy's own lane changes take 3-6 s). From every captured state s* and every first
action a0 on a grid around the policy's own mu(s*), it then rolls out one decision of a0
(held k steps) and the policy after it, with the timeout off and the same traffic for every
a0, and sums the discounted reward until the manoeuvre ends or ``--horizon`` s pass.

If the return peaks at a0 = mu(s*), the policy is at a maximum of the true return along
its first action (the deterministic policy gradient there is zero: the kink); if it peaks
elsewhere, the critic misleads the actor.

    python benchmarks/scripts/kink_probe.py RUN_DIR/checkpoints/m01_s0/ep05000.msgpack
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from jaxlc import config  # noqa: E402
from jaxlc.policy import actor_fn  # noqa: E402
from jaxlc.sim import env, road  # noqa: E402
from jaxlc.sim.reward import NONE  # noqa: E402
from jaxlc.study import checkpoint  # noqa: E402


def main(argv: Sequence[str] | None = None) -> dict[str, float]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("--envs", type=int, default=256)
    ap.add_argument("--steps", type=int, default=1500, help="env-steps to look for stalls")
    ap.add_argument("--at", type=float, default=8.0, help="s into the manoeuvre: captured")
    ap.add_argument("--horizon", type=float, default=20.0, help="s of each branch rollout")
    ap.add_argument("--spread", type=float, default=0.3, help="a0 in mu(s*) +- this")
    ap.add_argument("--points", type=int, default=25, help="a0 values")
    args = ap.parse_args(argv)

    params, meta = checkpoint.load(args.checkpoint)
    cfg = config.load(args.checkpoint.parents[2] / "config.toml")
    k = int(meta["k"])
    lenv, p = env.make(cfg, k=k)
    act = actor_fn(params, cfg.ddpg.hidden)
    at = round(args.at / p.dt)

    def drive(carry, key):  # the policy, no noise; capture each env's first stalled state
        obs, s, got, caught = carry
        nxt_obs, nxt, *_ = jax.vmap(lenv.step, (0, 0, 0, None))(
            jax.random.split(key, args.envs), s, act(obs), p
        )
        now = (nxt.ego.phase == env.RL) & (nxt.ego.steps == at) & ~got
        pick = lambda new, old: jnp.where(  # noqa: E731
            now.reshape(now.shape + (1,) * (new.ndim - 1)), new, old
        )
        caught = jax.tree.map(pick, (nxt_obs, nxt), caught)
        return (nxt_obs, nxt, got | now, caught), None

    keys = jax.random.split(jax.random.key(0), args.envs)
    obs, s = jax.vmap(lenv.reset, (0, None))(keys, p)
    init = (obs, s, jnp.zeros(args.envs, bool), (obs, s))
    (_, _, got, (obs_c, s_c)), _ = jax.jit(
        lambda c: jax.lax.scan(drive, c, jax.random.split(jax.random.key(1), args.steps))
    )(init)
    got = np.asarray(got)
    if not got.any():
        raise SystemExit(f"no manoeuvre of this checkpoint lasted {args.at} s: nothing stalls")
    obs_c, s_c = jax.tree.map(lambda a: a[got], (obs_c, s_c))
    mu = act(obs_c)[:, 0]  # (stalled,)
    offsets = jnp.linspace(-args.spread, args.spread, args.points)
    a0 = jnp.clip(mu[:, None] + offsets[None, :], -1.0, 1.0)  # (stalled, points)
    no_timeout = p.replace(manoeuvre_time_limit=1e6)
    horizon = round(args.horizon / p.dt)

    def branch(obs, s, first):  # one decision of `first` (held k steps), then the policy
        def body(carry, inp):
            obs, s, ret, live = carry
            i, key = inp
            a = jnp.where(i < k, first, act(obs)[0])
            obs, s, r, *_, info = lenv.step(key, s, jnp.reshape(a, (1,)), no_timeout)
            ret = ret + jnp.where(live, no_timeout.gamma**i * r, 0.0)
            live = live & (info["reason"] == NONE)
            return (obs, s, ret, live), None

        same_traffic = jax.random.split(jax.random.key(2), horizon)
        carry = (obs, s, jnp.float32(0.0), jnp.bool_(True))
        (_, _, ret, _), _ = jax.lax.scan(body, carry, (jnp.arange(horizon), same_traffic))
        return ret

    per_a0 = jax.vmap(branch, (None, None, 0))
    returns = np.asarray(jax.jit(jax.vmap(per_a0))(obs_c, s_c, a0))  # (stalled, points)
    own = returns[:, args.points // 2]  # offset 0: a0 = mu(s*)
    best = returns.argmax(axis=1)
    gain = returns.max(axis=1) - own
    at_own = np.abs(np.asarray(offsets)[best]) <= args.spread / (args.points - 1) + 1e-6
    out = {
        "stalled_states": int(got.sum()),
        "envs": args.envs,
        "peak_at_own_action": float(at_own.mean()),
        "median_gain": float(np.median(gain)),
        "median_best_offset": float(np.median(np.asarray(offsets)[best])),
        "median_abs_offset_m": float(
            np.median(np.abs(np.asarray(road.lateral_offset(s_c.ego, p))))
        ),
    }
    print(
        f"{out['stalled_states']} of {args.envs} envs stalled {args.at:g} s into a manoeuvre "
        f"(median |offset| {out['median_abs_offset_m']:.2f} m). The discounted return over "
        f"{args.horizon:g} s peaks at the policy's own first action (within one grid step of "
        f"{2 * args.spread / (args.points - 1):.3f}) in {out['peak_at_own_action']:.0%} of "
        f"them; median gain of the best a0 over mu(s*): {out['median_gain']:.2f}, at a median "
        f"offset of {out['median_best_offset']:+.3f} from mu(s*)."
    )
    return out


if __name__ == "__main__":
    main()
