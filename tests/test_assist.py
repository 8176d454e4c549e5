"""The gap-fitting controller (``jaxlc.sim.controller.fitting_action``) and the driver-assist
layer that adds it under a policy (``env.assist = "fitting"``)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import jaxlc
from jaxlc import config
from jaxlc.evaluation import cases
from jaxlc.sim.controller import (
    FIT_GO_AFTER,
    baseline_action,
    fitting_action,
    scripted_action,
)
from jaxlc.sim.observation import INDEX, MIRROR_SIGNS, OBS_DIM, scale

JOINT = config.load(config.CONFIG_DIR / "joint.toml")


def _params(**env):
    return jaxlc.make(dataclasses.replace(JOINT, env=dataclasses.replace(JOINT.env, **env)))[1]


def _obs(p, **raw: float) -> jnp.ndarray:
    """An observation from raw values (m, s, m/s): a straight road, the ego on its origin
    lane's centre line (the target one lane up), no heading, at 25 m/s; missing vehicles read
    as the simulator writes them (gap 100 m, dv 0)."""
    values = {"v": 25.0, "offset": -3.7, "lead_gap": 100.0, "lag_gap": 100.0, "own_gap": 100.0}
    values.update(raw)
    obs = np.zeros(OBS_DIM, np.float32)
    for name, value in values.items():
        obs[INDEX[name]] = value / float(scale(name, p))
    return jnp.asarray(obs)


P = _params()


def test_a_short_lead_holds_the_lane_and_brakes() -> None:
    obs = _obs(P, lead_gap=15.0)  # 0.6 s behind the target lane's lead
    lat, lon = np.asarray(fitting_action(obs, P))
    assert lat == 0.0  # on the origin lane's centre line with no heading: nothing to steer
    assert lon == -1.0
    assert float(scripted_action(obs, P)[0]) > 0.1  # the baseline steers across at once


def test_a_short_lag_is_outrun_when_slower_and_let_pass_when_faster() -> None:
    slower = fitting_action(_obs(P, lag_gap=15.0, lag_dv=-2.0), P)
    faster = fitting_action(_obs(P, lag_gap=15.0, lag_dv=2.0), P)
    np.testing.assert_array_equal(np.asarray(slower), [0.0, 1.0])
    np.testing.assert_array_equal(np.asarray(faster), [0.0, -1.0])


@pytest.mark.parametrize(
    "raw",
    [
        {"lead_gap": 60.0, "lag_gap": 60.0},  # fits: 2.4 s either side
        {"lead_gap": 12.0, "lag_gap": 12.0},  # 24 m cannot hold 1 s either side at 25 m/s
        {"lead_gap": 15.0, "offset": -2.0},  # the body is over the line already
    ],
)
def test_it_changes_lane_as_the_baseline_once_it_goes(raw: dict) -> None:
    obs = _obs(P, **raw)
    lat, lon = np.asarray(fitting_action(obs, P))
    assert lat == float(scripted_action(obs, P)[0]) != 0.0
    fits = raw.get("lag_gap") == 60.0
    assert lon == (0.0 if fits else -1.0)  # speed adjusted only while the gap does not fit


def test_after_go_after_the_acceptance_headway_is_enough() -> None:
    short = _obs(P, lead_gap=15.0)  # 0.6 s: under the norm, over gap_time_headway (0.5 s)
    shorter = _obs(P, lead_gap=10.0)  # 0.4 s
    assert float(fitting_action(short, P, time=FIT_GO_AFTER - 0.1)[0]) == 0.0
    assert float(fitting_action(short, P, time=FIT_GO_AFTER)[0]) > 0.1
    assert float(fitting_action(shorter, P, time=FIT_GO_AFTER)[0]) == 0.0
    # the observed time, where the env shows it, is read the same way
    seen = short.at[INDEX["time"]].set(FIT_GO_AFTER / float(scale("time", P)))
    assert float(fitting_action(seen, P)[0]) > 0.1


def test_it_is_odd_in_the_lateral_action_and_even_in_the_longitudinal() -> None:
    rng = np.random.default_rng(3)
    obs = jnp.asarray(rng.normal(size=(256, OBS_DIM)), jnp.float32)
    obs = obs.at[:, INDEX["lead_gap"]].multiply(0.3).at[:, INDEX["lag_gap"]].multiply(0.3)
    a = np.asarray(fitting_action(obs, P))
    m = np.asarray(fitting_action(obs * jnp.asarray(MIRROR_SIGNS), P))
    np.testing.assert_array_equal(m, a * [-1.0, 1.0])
    assert 0 < np.mean(a[:, 1] != 0.0) < 1  # the cases hold both waiting and going


def test_the_baseline_row_under_an_assist_is_the_assist_alone() -> None:
    obs = _obs(P, lead_gap=15.0)
    assisted = _params(assist="fitting")
    np.testing.assert_array_equal(np.asarray(baseline_action(obs, assisted)), [0.0, 0.0])
    np.testing.assert_array_equal(
        np.asarray(baseline_action(obs, P)), np.asarray(scripted_action(obs, P))
    )


def test_the_assist_drives_as_the_controller_does_under_a_zero_policy() -> None:
    """A zero policy under ``env.assist = "fitting"`` runs the same lane changes as the
    controller acting itself with the manoeuvre time observed: the same ends, steps and the
    manoeuvre's start, on held-out cases."""
    assisted = dataclasses.replace(JOINT, env=dataclasses.replace(JOINT.env, assist="fitting"))
    timed = dataclasses.replace(JOINT, env=dataclasses.replace(JOINT.env, terminal_timeout=True))
    keys = cases.heldout_keys(0, 24)
    p = _params(terminal_timeout=True)
    zero = cases.evaluate_act(assisted, lambda o: jnp.zeros(o.shape[:-1] + (2,)), keys=keys)
    itself = cases.evaluate_act(timed, lambda o: fitting_action(o, p), keys=keys)
    for name in ("reason", "steps", "lcm_start", "lcm_end"):
        np.testing.assert_array_equal(zero[name], itself[name], err_msg=name)
    held = zero["steps"][zero["reason"] > 0]
    assert held.size >= 12  # most of the 24 cases reach a lane change and end it
    np.testing.assert_allclose(zero["peak_lat_acc"], itself["peak_lat_acc"], atol=1e-5)


def test_an_export_of_an_assisted_run_says_its_graph_is_a_residual() -> None:
    from jaxlc.export import _assist

    assert _assist(P) == {}
    said = _assist(_params(assist="fitting"))
    assert said["assist"] == "fitting" and "residual" in said["assist_note"]
