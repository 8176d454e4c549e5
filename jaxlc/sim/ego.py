"""The ego: its action, its longitudinal acceleration, its phases and the gap decision.

An episode of the ego goes through four phases (``state.PHASES``):
  WAIT   no ego; the next vehicle to enter the middle lane becomes the ego;
  CRUISE the ego follows IDM until it has travelled ``command_distance``;
  GAP    a left or right command is issued; gap selection looks for an acceptable gap
         (``gap.py``), adapting the ego's speed, for at most ``gap_time_limit`` s;
  RL     the action steers the ego (yaw acceleration) until success, out of bounds,
         collision or timeout.
The ego's longitudinal motion is ``ego_accel`` in every phase (with ``longitudinal =
"policy"`` plus the held second action's correction in the RL phase); its lateral motion is the
held action's yaw acceleration (``held_action``), integrated by ``motion.move``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxlc.sim import gap
from jaxlc.sim.idm import NO_LEADER_GAP, idm_with_params
from jaxlc.sim.motion import Motion
from jaxlc.sim.road import origin_lane, origin_y, road_curvature, target_frame
from jaxlc.sim.state import (
    CRUISE,
    GAP,
    RL,
    WAIT,
    Draws,
    Ego,
    EnvParams,
    EnvState,
    Traffic,
    action_dim,
)


def clean_action(action: Array, entry: int = 0) -> Array:
    """Entry ``entry`` of any action, NaN and inf included, as a finite value in [-1, 1]."""
    flat = jnp.reshape(action, (-1,))
    if flat.shape[0] <= entry:  # a static shape: a wrong action fails loudly, not clamped
        raise ValueError(
            f"the action needs {entry + 1} entries (env.longitudinal = 'policy' adds the "
            f"longitudinal one), got shape {jnp.shape(action)}"
        )
    a = flat[entry].astype(jnp.float32)
    return jnp.clip(jnp.nan_to_num(a, nan=0.0, posinf=1.0, neginf=-1.0), -1.0, 1.0)


def refreshes(steps: Array, k: Array) -> Array:
    """Whether the RL step taken after ``steps`` RL steps refreshes the held action: every
    ``k``-th, the first included [P]."""
    return steps % k == 0


def _hold(ego: Ego, value: Array, held: Array, p: EnvParams) -> Array:
    in_rl = ego.phase == RL
    refresh = in_rl & refreshes(ego.steps, p.k)
    return jnp.where(refresh, value, jnp.where(in_rl, held, 0.0))


def held_action(ego: Ego, action: Array, p: EnvParams) -> Array:
    """``()`` action executed this step: refreshed every k-th RL step, held in between [P],
    0 outside the RL phase."""
    return _hold(ego, clean_action(action), ego.held, p)


def held_long_action(ego: Ego, action: Array, p: EnvParams) -> Array | None:
    """``()`` longitudinal action executed this step (the action's second entry, held as the
    first), with ``longitudinal = "policy"``; None otherwise."""
    if p.longitudinal != "policy":
        return None
    return _hold(ego, clean_action(action, 1), ego.held_long, p)


def ego_accel(state: EnvState, p: EnvParams, held_long: Array | None = None) -> Array:
    """``()`` IDM acceleration of the ego toward its own-lane leader, "with adaptation" to the
    chosen gap once it looks for one: the lower of the two. With ``held_long`` (the policy's
    longitudinal action, ``longitudinal = "policy"``) the RL phase adds ``long_acc_bound *
    held_long`` to it, within [-idm_b_max, idm_a_max], and never accelerates the ego past its
    desired speed (the observation's speed bound, and a speed limit, hold)."""
    eg = state.ego
    in_rl = eg.phase == RL
    nb, x = target_frame(state.nb, eg, road_curvature(state, p), p)  # m along the target lane
    a_own = idm_with_params(eg.v, eg.v0, state.leader_gap, state.leader_v, p)
    seek_gap, seek_v = gap.target_leader(nb, x, eg.v, p)
    lead_gap = gap.net_gap(nb.a1_x, x, p.vehicle_length, nb.has_a1)
    adapt_gap = jnp.where(in_rl, lead_gap, seek_gap)
    # With no vehicle to adapt to (gap NO_LEADER_GAP), any finite speed gives a ~ free road.
    adapt_v = jnp.where(adapt_gap >= NO_LEADER_GAP, eg.v, jnp.where(in_rl, nb.a1_v, seek_v))
    a_adapt = idm_with_params(eg.v, eg.v0, adapt_gap, adapt_v, p)
    a = jnp.where(eg.phase >= GAP, jnp.minimum(a_own, a_adapt), a_own)
    if held_long is None:
        return a
    a_pol = jnp.clip(a + p.long_acc_bound * held_long, -p.idm_b_max, p.idm_a_max)
    a_pol = jnp.minimum(a_pol, jnp.maximum((eg.v0 - eg.v) / p.dt, a))
    return jnp.where(in_rl, a_pol, a)


def ego_phase(
    eg: Ego,
    m: Motion,
    a_ego: Array,
    held: Array,
    held_long: Array | None,
    spawned: Array,
    tr: Traffic,
    u: Draws,
    p: EnvParams,
) -> Ego:
    """The ego after the move: a spawned ego starts CRUISE at x = 0 in the middle lane with the
    entrant's speeds (``tr``, the traffic before inflow); a cruising ego that has travelled
    ``command_distance`` gets a left or right command (toward the road when the lane beside is
    missing) and enters GAP. RL steps and gap-search time are counted here."""
    origin = origin_lane(p)
    in_rl = eg.phase == RL
    phase = jnp.where(spawned, CRUISE, eg.phase)
    ex = jnp.where(spawned, 0.0, m.ego_x)
    command = (phase == CRUISE) & (ex >= p.command_distance)
    side = jnp.where(u.side < 0.5, 1, -1)
    target = origin + side
    target = jnp.where((target < 0) | (target >= p.lanes), origin - side, target)
    return Ego(
        phase=jnp.where(command, GAP, phase),
        x=ex,
        y=jnp.where(spawned, origin_y(p), m.ego_y),
        v=jnp.where(spawned, tr.next_v[origin], m.ego_v),
        v0=jnp.where(spawned, tr.next_v0[origin], eg.v0),
        accel=jnp.where(spawned, 0.0, a_ego),
        psi=jnp.where(spawned, 0.0, m.ego_psi),
        omega=jnp.where(spawned, 0.0, m.ego_omega),
        held=held,
        target=jnp.where(command, target, eg.target).astype(jnp.int32),
        steps=eg.steps + in_rl,
        gap_time=jnp.where(command, 0.0, eg.gap_time + p.dt * (eg.phase == GAP)),
        yielding=eg.yielding,
        ep_return=eg.ep_return,
        held_long=held_long,
    )


def gap_decision(
    ego: Ego, nb: gap.Neighbours, p: EnvParams, kappa: Array | None = None
) -> tuple[Array, Array]:
    """``(accept, no_gap)``: in GAP, accept the gap beside the ego, or give up once the time or
    distance limit is reached without one (x, the limit, in s)."""
    looking = ego.phase == GAP
    nb_m, x_m = target_frame(nb, ego, p.curvature if kappa is None else kappa, p)
    accept = looking & gap.beside_acceptable(nb_m, x_m, ego.v, p)
    no_gap = looking & ~accept & ((ego.gap_time >= p.gap_time_limit) | (ego.x >= p.gap_x_limit))
    return accept, no_gap


def parked_ego(p: EnvParams) -> Ego:
    """The ego of a reset: off the road (WAIT), at rest, its target the origin lane."""
    f0 = jnp.float32(0.0)
    ego = Ego(
        phase=jnp.int32(WAIT),
        x=f0,
        y=origin_y(p),
        v=f0,
        v0=f0 + p.desired_speed_max,
        accel=f0,
        psi=f0,
        omega=f0,
        held=f0,
        target=jnp.int32(origin_lane(p)),
        steps=jnp.int32(0),
        gap_time=f0,
        yielding=jnp.bool_(False),
        ep_return=f0,
        held_long=f0 if action_dim(p) > 1 else None,
    )
    return ego


def commanded(ego: Ego) -> Array:
    """``()`` bool: the ego got its command on this step (it entered GAP, ``ego_phase``)."""
    return (ego.phase == GAP) & (ego.gap_time == 0.0)


def outside(v: Array, speeds: tuple[float, float]) -> Array:
    """``()`` bool: ``v`` (m/s) is outside ``speeds``, the operating range ``(min, max)``."""
    return (v < speeds[0]) | (v > speeds[1])
