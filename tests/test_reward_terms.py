"""A fourth reward term through the public extension point (``reward.register`` and the
config's ``env.reward_terms``) shows in every output that lists the reward term by term: the
env's info, the training metrics, TensorBoard, the evaluation tables, the gym and gymnax
infos. None of those is edited for it: each iterates over the params' terms.

Also the whole manoeuvre's terms (``reward.MANOEUVRE``: r_long, r_lat, r_gap, r_speed) on
hand-worked cases, and in the env: off by default, summed into the reward when named."""

from __future__ import annotations

import csv
import dataclasses
import json
from types import SimpleNamespace as Ns

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxlc
from jaxlc import config, evaluate, sweep
from jaxlc.config import ConfigError, EnvConfig
from jaxlc.sim import reward
from jaxlc.sim.env import EnvParams
from jaxlc.study.rundir import RunDir

SMOKE = config.CONFIG_DIR / "smoke.toml"
NAMES = ["r_s", "r_e", "r_d", "r_centre"]


def centre_speed(x: reward.Inputs, p) -> jax.Array:
    """A made-up term that reads the step's offset and the ego's speed after it."""
    return -0.25 * jnp.abs(x.offset) * x.ego.v / 20.0


TERM = reward.register(reward.Term("r_centre", (), centre_speed))


@pytest.fixture(scope="module")
def cfg() -> config.Config:
    return config.load(
        SMOKE,
        [
            f"env.reward_terms={json.dumps(NAMES)}",
            "grid.k=[1]",
            "grid.memory=[256]",
            "train.episodes=20",
            "train.checkpoint_every=20",
        ],
    )


def test_a_term_is_named_once_and_an_unknown_one_is_refused():
    with pytest.raises(ValueError, match="registered already"):
        reward.register(reward.Term("r_s", (), centre_speed))
    assert reward.register(TERM) is TERM  # the same term again is fine
    with pytest.raises(ConfigError, match=r"env\.reward_terms.*r_nope"):
        EnvParams.from_config(EnvConfig(reward_terms=("r_s", "r_nope")))
    with pytest.raises(ConfigError, match=r"env\.reward_terms"):
        config.load(SMOKE, ['env.reward_terms=["r_s", "r_s"]'])


@pytest.mark.slow
def test_env_info_has_the_term_and_the_reward_is_the_sum(cfg):
    env, p = jaxlc.make(cfg)
    assert reward.names(p) == tuple(NAMES)

    def run(key):
        _, state = env.reset(key, p)

        def body(state, k):
            k_a, k_s = jax.random.split(k)
            a = jax.random.uniform(k_a, (1,), minval=-1.0, maxval=1.0)
            _, nxt, r, _, _, info = env.step(k_s, state, a, p)
            return nxt, (r, info, nxt.ego.v)

        return jax.lax.scan(body, state, jax.random.split(key, 1500))[1]

    r, info, v = jax.jit(run)(jax.random.key(0))
    rl = np.asarray(info["rl_step"])
    assert rl.sum() > 50
    got = np.asarray(info["r_centre"])
    want = -0.25 * np.abs(np.asarray(info["offset"])) * np.asarray(v) / 20.0
    np.testing.assert_allclose(got[rl], want[rl] * cfg.env.reward_scale, rtol=1e-6)
    assert np.all(got[~rl] == 0.0)
    total = sum(np.asarray(info[n]) for n in NAMES)
    np.testing.assert_allclose(np.asarray(r), total, rtol=1e-6, atol=1e-6)


@pytest.mark.slow
def test_training_metrics_tensorboard_and_evaluation_have_the_term(tmp_path_factory, cfg):
    pytest.importorskip("tensorboardX", reason="optional: pip install -e '.[track]'")
    from jaxlc.study import tracking

    out, tb = tmp_path_factory.mktemp("run"), tmp_path_factory.mktemp("tb")
    summary = sweep.run_sweep(cfg, out, progress=False, tensorboard=tb)
    eps = RunDir.load_npz(RunDir(out).episodes)
    # The terms in the config's order (a jitted dict comes back sorted), after the return.
    assert list(eps)[:8] == ["ret", "steps", "reason", *NAMES, "at_step"]
    n = int(eps["episodes"][0])
    assert n >= 20
    terms = {name: eps[name][0, :n] for name in NAMES}
    assert np.all(terms["r_centre"] < 0)  # every manoeuvre is off centre at its start
    np.testing.assert_allclose(eps["ret"][0, :n], sum(terms.values()), rtol=1e-4, atol=1e-2)
    curves = tracking.read_scalars(tb / tracking.run_name(summary["models"][0]))
    last = terms["r_centre"][max(0, n - 100) :].mean()
    np.testing.assert_allclose(curves["reward/r_centre_last100"][-1][1], last, rtol=1e-5)

    assert evaluate.main([str(out), "--no-figures", "--cases", "8", "--lane-changes", "0"]) == 0
    with open(RunDir(out).eval / "eval.csv") as f:
        rows = list(csv.DictReader(f))
    assert set(NAMES) <= set(rows[0])
    assert list(np.load(RunDir(out).eval / "cases.npz").files)[3:7] == NAMES
    performed = [r for r in rows if int(r["performed"]) > 0]
    assert performed and all(float(r["r_centre"]) < 0 for r in performed)
    for r in performed:  # the row's return is its terms' sum
        parts = sum(float(r[name]) for name in NAMES)
        assert float(r["avg_return"]) == pytest.approx(parts, rel=1e-4, abs=1e-2)


@pytest.mark.slow
def test_gym_and_gymnax_infos_have_the_term(cfg):
    pytest.importorskip("gymnasium")
    from jaxlc.gym import LaneChangeGymEnv

    env = LaneChangeGymEnv(config=cfg)
    env.reset(seed=0)
    _, r, _, _, info = env.step(np.zeros(1, np.float32))
    assert set(NAMES) <= set(info)
    assert info["r_centre"] < 0
    assert sum(info[n] for n in NAMES) == pytest.approx(r, rel=1e-5, abs=1e-5)

    genv, gp = jaxlc.make_gymnax(cfg)
    obs, state = genv.reset(jax.random.key(0), gp)
    _, _, r, _, _, info = genv.step(jax.random.key(1), state, jnp.zeros(1), gp)
    assert set(NAMES) <= set(info)
    assert float(info["r_centre"]) < 0
    assert float(sum(info[n] for n in NAMES)) == pytest.approx(float(r), rel=1e-5, abs=1e-5)


# The whole manoeuvre's terms (formerly tests/test_manoeuvre_reward.py).
WEIGHTS = dict(w_long_acc=2.0, w_long_jerk=0.5, w_lat_acc=1.0, w_lat_jerk=0.5)
WEIGHTS |= dict(w_headway=2.0, w_speed=4.0)
P = EnvParams.from_config(dataclasses.replace(config.EnvConfig(), **WEIGHTS))
DT = float(P.dt)


def _inputs(ego: Ns, before: Ns | None = None, **kw) -> reward.Inputs:
    z = jnp.float32(0.0)
    return reward.Inputs(
        z, z, z, jnp.bool_(False), ego, kw.get("nb"), before, kw.get("gaps"), kw.get("overlap")
    )


def test_longitudinal_comfort_is_acceleration_and_jerk() -> None:
    x = _inputs(Ns(accel=1.5), Ns(accel=-0.5))
    want = -2.0 * 1.5 - 0.5 * abs(2.0 / DT)
    assert float(reward.longitudinal_comfort(x, P)) == pytest.approx(want, rel=1e-6)


def test_lateral_comfort_costs_only_the_excess_over_iso_11270() -> None:
    # a_y = 20 * 0.2 = 4 m/s^2 (1 over 3); from 20 * 0.19 = 3.8 the jerk is 0.2/dt m/s^3
    x = _inputs(Ns(v=20.0, omega=0.2), Ns(v=20.0, omega=0.19))
    jerk = 0.2 / DT
    want = -1.0 * (4.0 - 3.0) - 0.5 * max(jerk - 5.0, 0.0)
    assert float(reward.lateral_comfort(x, P)) == pytest.approx(want, rel=1e-5)
    inside = _inputs(Ns(v=20.0, omega=0.1), Ns(v=20.0, omega=0.1))  # 2 m/s^2, no jerk
    assert float(reward.lateral_comfort(inside, P)) == 0.0


def test_headway_shortfall_counts_from_the_overlap() -> None:
    nb = Ns(has_a1=jnp.bool_(True), has_b1=jnp.bool_(True), b1_v=jnp.float32(10.0))
    ego = Ns(v=jnp.float32(15.0))
    gaps = (jnp.float32(9.0), jnp.float32(20.0))  # lead 9 m at 15 m/s: 0.6 s; lag 20/10 = 2 s
    x = _inputs(ego, nb=nb, gaps=gaps, overlap=jnp.bool_(True))
    assert float(reward.headway_shortfall(x, P)) == pytest.approx(-2.0 * (0.9 - 0.6), rel=1e-5)
    beside = x._replace(overlap=jnp.bool_(False))  # still wholly in its own lane: none
    assert float(reward.headway_shortfall(beside, P)) == 0.0
    no_lead = x._replace(nb=Ns(has_a1=jnp.bool_(False), has_b1=nb.has_b1, b1_v=nb.b1_v))
    assert float(reward.headway_shortfall(no_lead, P)) == 0.0


def test_speed_keeping_is_the_relative_speed_error() -> None:
    x = _inputs(Ns(v=18.0, v0=24.0))
    assert float(reward.speed_keeping(x, P)) == pytest.approx(-4.0 * 6.0 / 24.0)


@pytest.fixture(scope="module")
def rollout() -> tuple[dict, dict]:
    """3,000 steps of 8 envs under a constant left command, the seven terms named."""
    names = [t.name for t in (*reward.PAPER, *reward.MANOEUVRE)]
    over = [f"env.{k}={v}" for k, v in WEIGHTS.items()] + [f"env.reward_terms={names}"]
    env, p = jaxlc.make(config.load(overrides=[o.replace("'", '"') for o in over]))

    def run(key):
        _, s = env.reset(key, p)

        def body(s, k):
            _, s, r, _, _, info = env.step(k, s, jnp.ones(1), p)
            return s, (r, info)

        return jax.lax.scan(body, s, jax.random.split(key, 3000))[1]

    r, info = jax.jit(jax.vmap(run))(jax.random.split(jax.random.key(4), 8))
    return np.asarray(r), jax.tree.map(np.asarray, info)


def test_the_terms_sum_to_the_reward_and_are_costs(rollout) -> None:
    r, info = rollout
    names = [t.name for t in (*reward.PAPER, *reward.MANOEUVRE)]
    rl = info["rl_step"]
    assert rl.sum() > 100  # the rollout reached the manoeuvre
    np.testing.assert_allclose(sum(info[n] for n in names), r, rtol=1e-5, atol=1e-5)
    for n in ("r_long", "r_lat", "r_gap", "r_speed"):
        assert (info[n] <= 0).all() and (info[n][~rl] == 0).all(), n
    assert (info["r_speed"][rl] < 0).any() and (info["r_long"][rl] < 0).any()


@pytest.mark.slow
def test_the_default_reward_names_none_of_them() -> None:
    env, p = jaxlc.make()
    assert reward.names(p) == ("r_s", "r_e", "r_d")
    assert all(getattr(p, w) == 0.0 for t in reward.MANOEUVRE for w in t.weights if w[:2] == "w_")
    _, s = env.reset(jax.random.key(0), p)
    *_, info = env.step(jax.random.key(1), s, jnp.zeros(1), p)
    assert not {t.name for t in reward.MANOEUVRE} & set(info)
