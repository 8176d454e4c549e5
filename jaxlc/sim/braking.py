"""Braking events: any vehicle brakes hard for a while, as a Poisson process per vehicle.

A vehicle not already braking starts an event on a step with probability ``1 - exp(-rate*dt)``
(``braking_rate``, per vehicle-hour in the config), at a deceleration drawn from
``U(braking_decel_min, _max)`` for ``U(braking_time_min, _max)`` s; while it lasts the
vehicle's acceleration is the lower of its IDM's and minus that deceleration, and its follower's
IDM answers as to any leader. Every draw is the step's (``state.TrafficDraws``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from jaxlc.sim.leaders import ego_neighbours
from jaxlc.sim.state import CRUISE, Ego, EnvParams, Traffic, TrafficDraws, between


def braked(acc: Array, tr: Traffic) -> Array:
    """``(lanes, slots)`` the IDM accelerations ``acc`` with the events under way applied."""
    return jnp.where(tr.brake_left > 0.0, jnp.minimum(acc, -tr.brake_acc), acc)


class Events(NamedTuple):
    traffic: Traffic
    eligible: Array  # (lanes, slots) bool: on the road and not braking, so it may start one
    started: Array  # (lanes, slots) bool: an event starts on this step


def start_probability(p: EnvParams) -> Array:
    """``()`` the probability that a vehicle not braking starts an event on one step."""
    return -jnp.expm1(-p.braking_rate * p.dt)


def advance(tr: Traffic, u: TrafficDraws, p: EnvParams) -> Events:
    """Every event one step on, and the events that start (``tr``: the traffic after the
    step's move and inflow; an entrant comes in with none)."""
    left = jnp.maximum(tr.brake_left - p.dt, 0.0)
    eligible = tr.active & (left <= 0.0)
    started = eligible & (u.brake_fire < start_probability(p))
    traffic = tr.replace(
        brake_left=jnp.where(
            started, between(u.brake_time, p.braking_time_min, p.braking_time_max), left
        ),
        brake_acc=jnp.where(
            started, between(u.brake_acc, p.braking_decel_min, p.braking_decel_max), tr.brake_acc
        ),
    )
    return Events(traffic, eligible, started)


def counts(ev: Events, eg: Ego, p: EnvParams) -> dict[str, Array]:
    """The step's braking events for ``info``: vehicles that could start one and that did
    (``()`` int32 each), and ``brake_near``: how many of them are around the ego
    (``leaders.ego_neighbours``: its lead and lag in the target lane, its own lane's leader)."""
    near = ego_neighbours(ev.traffic, eg, p) & (eg.phase >= CRUISE)
    return {
        "brake_eligible": jnp.sum(ev.eligible, dtype=jnp.int32),
        "brake_started": jnp.sum(ev.started, dtype=jnp.int32),
        "brake_near": jnp.sum(ev.started & near, dtype=jnp.int32),
    }
