"""The gap-fitting controller (``jaxlc.sim.controller.fitting_action``) and the driver-assist
layer that adds it under a policy (``env.assist = "fitting"``)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxlc
from jaxlc import config
from jaxlc.evaluation import cases
from jaxlc.evaluation import keys as streams
from jaxlc.sim.controller import (
    FIT_GO_AFTER,
    baseline_action,
    fitting_action,
    scripted_action,
)
from jaxlc.sim.env import RL
from jaxlc.sim.observation import INDEX, MIRROR_SIGNS, OBS_DIM, scale

from .conftest import changed_env_keys

JOINT = config.load(config.CONFIG_DIR / "joint.toml")


def _cfg(**env) -> config.Config:
    return dataclasses.replace(JOINT, env=dataclasses.replace(JOINT.env, **env))


def _params(**env):
    return jaxlc.make(_cfg(**env))[1]


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


@pytest.mark.slow
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


@pytest.mark.slow
def test_the_assist_drives_as_the_controller_does_under_a_zero_policy() -> None:
    """A zero policy under ``env.assist = "fitting"`` runs the same lane changes as the
    controller acting itself with the manoeuvre time observed: the same ends, steps and the
    manoeuvre's start, on held-out cases."""
    assisted, timed = _cfg(assist="fitting"), _cfg(terminal_timeout=True)
    keys = streams.stream(0, streams.HELDOUT, range(24))
    p = _params(terminal_timeout=True)
    zero = cases.evaluate_act(assisted, lambda o: jnp.zeros(o.shape[:-1] + (2,)), keys=keys)
    itself = cases.evaluate_act(timed, lambda o: fitting_action(o, p), keys=keys)
    for name in ("reason", "steps", "lcm_start", "lcm_end"):
        np.testing.assert_array_equal(zero[name], itself[name], err_msg=name)
    held = zero["steps"][zero["reason"] > 0]
    assert held.size >= 12  # most of the 24 cases reach a lane change and end it
    np.testing.assert_allclose(zero["peak_lat_acc"], itself["peak_lat_acc"], atol=1e-5)


def test_an_export_of_an_assisted_run_says_its_graph_is_a_residual() -> None:
    from jaxlc.policy import _assist

    assert _assist(P) == {}
    said = _assist(_params(assist="fitting"))
    assert said["assist"] == "fitting" and "residual" in said["assist_note"]
    assert "holds" not in said["assist_note"] and said["assist_authority"] == 1.0
    held = _assist(_params(assist="fitting_hold", assist_authority=0.1))
    assert "holds the origin lane" in held["assist_note"]
    assert held["assist_authority"] == pytest.approx(0.1)


ENV = jaxlc.make(JOINT)[0]


@jax.jit
def _drive(p, scale: jax.Array) -> tuple[jax.Array, ...]:
    """``(envs, steps)`` phase, lateral position and speed of 16 envs over 600 steps of random
    joint actions ``scale * U(-1, 1)^2`` (``scale`` (2,)); one compile per static config."""

    def one(key):
        k_reset, k_run = jax.random.split(key)
        _, s = ENV.reset(k_reset, p)

        def body(s, k):
            k_a, k_s = jax.random.split(k)
            a = scale * jax.random.uniform(k_a, (2,), minval=-1.0, maxval=1.0)
            s2 = ENV.step(k_s, s, a, p)[1]
            return s2, (s2.ego.phase, s2.ego.y, s2.ego.v)

        return jax.lax.scan(body, s, jax.random.split(k_run, 600))[1]

    return jax.vmap(one)(jax.random.split(jax.random.key(7), 16))


def _rollout(assist: str, authority: float, lat: float, lon: float) -> list[np.ndarray]:
    p = _params(assist=assist, assist_authority=authority)
    return [np.asarray(x) for x in _drive(p, jnp.asarray([lat, lon]))]


@pytest.mark.slow
def test_the_residual_acts_through_its_authority_alone() -> None:
    """``env.assist_authority`` w scales the policy's residual: (w, a) drives as (1, w a), bit
    for bit (w a power of 2), and w = 0 drives as a zero policy; the same actions at full
    authority drive elsewhere (the authority is traced: one compile)."""
    quarter, full_scaled = _rollout("fitting", 0.25, 1, 1), _rollout("fitting", 1, 0.25, 0.25)
    for got, want in zip(quarter, full_scaled, strict=True):
        np.testing.assert_array_equal(got, want)
    for got, want in zip(_rollout("fitting", 0, 1, 1), _rollout("fitting", 1, 0, 0), strict=True):
        np.testing.assert_array_equal(got, want)
    assert (quarter[0] == RL).sum() > 100  # the residual acted on many RL steps
    full = _rollout("fitting", 1, 1, 1)
    assert np.abs(full[1] - quarter[1]).max() > 0.1  # m: a residual at full authority moves the ego


@pytest.mark.slow
def test_a_holding_assist_executes_its_own_lateral_action_alone() -> None:
    """Under ``"fitting_hold"`` a lateral residual at full authority changes nothing while the
    assist holds the origin lane: each env drives as under a zero policy until the zero
    policy's ego first leaves its lateral position in the RL phase (the assist goes); under
    ``"fitting"`` the same residual moves the ego off it at once."""
    zero = _rollout("fitting_hold", 1, 0, 0)
    held, unheld = _rollout("fitting_hold", 1, 1, 0), _rollout("fitting", 1, 1, 0)
    holds, moved = 0, 0
    for env in range(16):
        phase, y = zero[0][env], zero[1][env]
        first = int(np.argmax(phase == RL))  # the first RL step
        assert phase[first] == RL
        go = first + int(np.argmax(y[first:] != y[first]))  # the first step it moved
        holds += go - first - 1  # the first RL step is the acceptance's
        for got, want in zip(held, zero, strict=True):
            np.testing.assert_array_equal(got[env, :go], want[env, :go])
        if go > first + 1:
            moved += unheld[1][env, first + 1] != y[first + 1]  # the residual moves it at once
    assert holds >= 6  # steps held in the first manoeuvres: the property was exercised
    assert moved >= 1


def test_joint_assist_toml_is_joint_toml_with_the_assist_keys() -> None:
    """configs/joint_assist.toml spells out every key and differs from configs/joint.toml
    only in the assist, its authority and the headway weight (the study beside it is like
    for like with the joint study)."""
    assert changed_env_keys("joint_assist.toml", JOINT) == {
        "assist",
        "assist_authority",
        "w_headway",
    }
    on = config.load(config.CONFIG_DIR / "joint_assist.toml")
    assert (on.env.assist, on.env.assist_authority) == ("fitting_hold", 0.1)
    assert all(getattr(on, t) == getattr(JOINT, t) for t in ("ddpg", "train", "grid"))
