"""EnvParams: each env setting declared once (default, bounds, unit, static or traced) and read
by the TOML loader and ``jaxlc.make`` alike, passed traced and vmapped over drawn tasks, and a
manoeuvre that starts exactly one lane width from its target."""

import ast
import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxlc import config
from jaxlc.config import EnvConfig
from jaxlc.sim import reward, road
from jaxlc.sim.env import RL, EnvParams, LaneChangeEnv
from jaxlc.sim.params import STATIC, settings

ENV = LaneChangeEnv()
# The fields that are no [env] key: read from the table, or handed in by the learner.
DERIVED = {
    *("mobil_deciders", "curvature_min", "curvature_max", "curvature_drawn", "drawn", "ranges"),
    *("gamma", "k"),
}
# the source of the traffic's draws: None (the traffic's own), no leaf
DERIVED |= {"draws"}


def test_every_env_config_field_is_a_param_converted_by_the_table():
    params = {f.name for f in dataclasses.fields(EnvParams)}
    keys = {f.name for f in dataclasses.fields(EnvConfig)}
    assert keys - params == {"warmup_time"}  # held as warmup_steps
    assert params - keys == DERIVED | {"warmup_steps"}
    cfg = EnvConfig(entry_speed_max=72.0, inflow_max=3600.0, lane_width=3.5, border=4.0)
    p = EnvParams.from_config(cfg)
    assert p.entry_speed_max == pytest.approx(20.0)  # km/h -> m/s
    assert p.inflow_max == pytest.approx(1.0)  # veh/h -> veh/s
    assert (p.lane_width, p.border) == (3.5, 4.0)  # taken as they are
    # Static fields are not leaves: a vmapped batch may differ in every other field.
    leaves = len(jax.tree_util.tree_leaves(p))
    statics = STATIC | {"warmup_steps", "mobil_deciders", "curvature_drawn", "reward_terms"}
    # draws: None, no leaf; ranges: () unless a key is a range
    assert leaves == len(params) - len(statics) - 2


def test_env_params_spells_env_config_in_its_order_with_its_converted_defaults():
    """The [env] keys are EnvParams' settings, in their order (the resolved config.toml's and
    the pytree's), then the derived fields; their defaults are the config's."""
    names = [f.name for f in dataclasses.fields(EnvParams)]
    keys = [f.metadata["key"] or f.name for f in settings()]
    assert keys == [f.name for f in dataclasses.fields(EnvConfig)]
    assert set(names[len(keys) :]) == DERIVED
    assert EnvParams() == EnvParams.from_config(EnvConfig())
    assert EnvParams().gamma == config.DDPGConfig().gamma  # the learner's default discount
    assert STATIC == {
        "lanes", "slots_per_lane", "longitudinal", "assist", "mobil", "braking",
        "warmup_steps", "mobil_deciders", "curvature_drawn", "drawn", "reward_terms",
        "operating_speed", "manoeuvre_distance", "manoeuvre_time_max", "range_edge_share",
        "yaw_rate_obs",
    }  # fmt: skip


def test_each_setting_is_declared_once_with_its_default_bounds_unit_and_staticness():
    """One declaration per setting, in EnvParams' class body: EnvConfig's fields carry that
    declaration's metadata (no second copy to drift), and every setting states its unit,
    bounds (or choices) and whether it is static; static is what flax sees."""
    for f in settings():
        m = f.metadata
        assert isinstance(m["unit"], str) and isinstance(m["static"], bool), f.name
        assert m["static"] == (not m["pytree_node"]) == (f.name in STATIC), f.name
        number = isinstance(m["default"], int | float) and not isinstance(m["default"], bool)
        assert (m["lo"] is not None) == number, f"{f.name}: a number needs bounds"
        if number:  # the default is allowed
            assert m["lo"] <= m["default"] and (m["hi"] is None or m["default"] <= m["hi"])
        key = m["key"] or f.name
        assert EnvConfig.__dataclass_fields__[key].metadata == m, key
        assert getattr(EnvConfig(), key) == m["default"], key
    # and no class of jaxlc/config.py declares an [env] key a second time
    tree = ast.parse(Path(config.__file__).read_text())
    declared = {
        node.target.id
        for cls in ast.walk(tree)
        if isinstance(cls, ast.ClassDef)
        for node in cls.body
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
    }
    assert "actor_lr" in declared  # (the scan sees the other tables)
    assert not declared & {f.name for f in dataclasses.fields(EnvConfig)}


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ("env.lanes=9", "config key 'env.lanes': must be >= 2 and <= 8, got 9"),
        ("env.dt=0.0", "config key 'env.dt': must be > 0 and <= 1, got 0.0"),
        ("env.entry_speed_max=201", "config key 'env.entry_speed_max': must be >= 0 and <= 200"),
        ("env.assist='fit'", "config key 'env.assist': must be one of 'none', 'fitting'"),
        ("env.warmup_time=-1", "config key 'env.warmup_time': must be >= 0 and <= 600, got -1"),
        ("env.curvature=[0.0, 0.02]", "config key 'env.curvature': must be >= -0.01 and <= 0.01"),
        ("env.mobil=1", "config key 'env.mobil': must be true or false, got 1"),
        ("env.lane_widht=3.0", "unknown config key 'env.lane_widht'; allowed: assist, "),
    ],
)
def test_the_toml_loader_refuses_a_value_out_of_its_declared_bounds(override, words):
    with pytest.raises(config.ConfigError) as err:
        config.load(None, [override])
    assert str(err.value).startswith(words), str(err.value)


def test_an_old_run_config_migrates_to_todays_keys_in_one_function(tmp_path):
    """A resolved config from before 2026-11-23 (no gap_min_ttc, symmetric_actor,
    mirror_pairs; ddpg.td3 in place of ddpg.learner) reads as the run behaved; the same file
    read as a user's (not resolved) takes today's defaults for the keys it omits."""
    from jaxlc.study.rundir import RunDir

    today = config.Config()
    text = config.to_toml(today)
    assert config.to_toml(config.from_dict(config.migrate(today.to_dict()))) == text
    old = [
        x
        for x in text.splitlines()
        if not x.startswith(("gap_min_ttc", "symmetric_", "mirror_pairs", "learner"))
    ]
    old.insert(old.index("[ddpg]") + 1, "td3 = true")
    (tmp_path / "config.toml").write_text("\n".join(old) + "\n")
    ran = RunDir(tmp_path).load_config()
    assert ran.env.gap_min_ttc == 0.0 and ran.ddpg.learner == "td3"
    assert not ran.ddpg.symmetric_actor and not ran.ddpg.mirror_pairs
    assert ran.env == dataclasses.replace(today.env, gap_min_ttc=0.0)
    user = config.load(tmp_path / "config.toml")
    assert user.ddpg.learner == "td3" and user.ddpg.symmetric_actor and user.env == today.env
    assert [v for v, _, _ in config.VERSIONS] == sorted(v for v, _, _ in config.VERSIONS)


def _drawn(key, n: int, base: EnvParams, **ranges) -> EnvParams:
    """``n`` params with the fields in ``ranges`` drawn from U(lo, hi), stacked on axis 0."""
    keys = jax.random.split(key, len(ranges))
    drawn = {
        name: jax.random.uniform(k, (n,), minval=lo, maxval=hi)
        for k, (name, (lo, hi)) in zip(keys, ranges.items(), strict=True)
    }
    stacked = jax.tree.map(lambda x: jnp.full((n,), x, jnp.float32), base)
    return stacked.replace(**drawn)


def _episode(steps: int, action: float):
    """``(key, params) -> per-step outputs`` of one env under a constant action."""

    def one(key, p):
        k_reset, k_run = jax.random.split(key)
        _, state = ENV.reset(k_reset, p)

        def body(state, k):
            _, nxt, _, _, _, info = ENV.step(k, state, jnp.full((1,), action), p)
            offset = road.lateral_offset(nxt.ego, p)
            out = (nxt.ego.phase == RL, offset, info["reason"], nxt.traffic.inflow, nxt.ego)
            return nxt, out

        return jax.lax.scan(body, state, jax.random.split(k_run, steps))[1]

    return one


def _run(steps: int, action: float):
    """One jitted program: envs with their own params (a batch axis), a constant action."""
    return jax.jit(jax.vmap(_episode(steps, action)))


@pytest.mark.slow
def test_a_manoeuvre_starts_one_lane_width_from_its_target_with_params_traced():
    """The start-offset hazard: with border = lane width (the paper's), a start a rounding
    step past W would end the manoeuvre out of bounds at once. 64 envs, each with its own
    lane width (traced, vmapped), driving straight (action 0) on a straight road: every RL
    step's offset is exactly +-W, and no manoeuvre ends out of bounds."""
    base = EnvParams.from_config(config.load(overrides=["env.warmup_time=5.0"]).env)
    n = 64
    widths = jax.random.uniform(jax.random.key(3), (n,), minval=2.0, maxval=6.0)
    p = _drawn(jax.random.key(4), n, base, inflow_min=(0.3, 0.4), inflow_max=(0.4, 0.5))
    p = p.replace(lane_width=widths, border=widths)
    in_rl, offset, why, _, _ = _run(1500, 0.0)(jax.random.split(jax.random.key(5), n), p)
    in_rl, offset, why = np.asarray(in_rl), np.asarray(offset), np.asarray(why)
    assert in_rl.sum() > 1000  # many manoeuvres' steps were looked at
    w = np.broadcast_to(np.asarray(widths)[:, None], offset.shape)
    np.testing.assert_array_equal(np.abs(offset[in_rl]), w[in_rl])
    assert not np.any(why == reward.OUT_OF_BOUNDS)
    assert np.any(why == reward.TIMEOUT)


@pytest.mark.slow
def test_a_vmapped_batch_of_drawn_tasks_runs_in_one_program():
    """64 envs, each with its own road curvature, inflow range and yielding probability,
    in one compiled program; each env keeps to its own task."""
    base = EnvParams.from_config(config.load(overrides=["env.warmup_time=5.0"]).env)
    n = 64
    p = _drawn(
        jax.random.key(6),
        n,
        base,
        curvature=(-0.004, 0.004),
        inflow_min=(0.15, 0.25),
        inflow_max=(0.3, 0.45),
    )
    p = p.replace(p_yield=jnp.where(jnp.arange(n) % 2 == 0, 0.0, 1.0))
    keys = jax.random.split(jax.random.key(7), n)
    in_rl, _, why, inflow, ego = _run(1200, 0.3)(keys, p)
    inflow = np.asarray(inflow)  # (envs, steps, lanes)
    lo, hi = np.asarray(p.inflow_min)[:, None, None], np.asarray(p.inflow_max)[:, None, None]
    assert np.all((inflow >= lo * (1 - 1e-6)) & (inflow <= hi * (1 + 1e-6)))
    rl = np.asarray(in_rl)
    yielding = np.asarray(ego.yielding)
    even = np.arange(n) % 2 == 0
    assert rl[even].any() and rl[~even].any()
    assert not yielding[even][rl[even]].any()  # p_yield = 0: no lag ever yields
    assert yielding[~even][rl[~even]].all()  # p_yield = 1: every lag yields
    # The observation's curvature entry is each env's own road.
    obs = jax.jit(jax.vmap(lambda k, q: ENV.reset(k, q)[0]))(keys, p)
    from jaxlc.sim.observation import INDEX, scale

    kappa = np.asarray(obs[:, INDEX["curvature"]]) * scale("curvature", base)
    np.testing.assert_allclose(kappa, np.asarray(p.curvature), rtol=1e-6, atol=1e-9)
    # An env of the batch is the same env run alone with its params closed over: the same
    # phases and ends, step for step (reals to float32 rounding: tests/test_rollout_golden.py).
    i = 3
    alone = base.replace(**{f: float(getattr(p, f)[i]) for f in ("curvature", "p_yield")})
    alone = alone.replace(inflow_min=float(p.inflow_min[i]), inflow_max=float(p.inflow_max[i]))
    rl_1, _, why_1, _, _ = jax.jit(lambda k: _episode(1200, 0.3)(k, alone))(keys[i])
    np.testing.assert_array_equal(np.asarray(rl_1), rl[i])
    np.testing.assert_array_equal(np.asarray(why_1), np.asarray(why)[i])
    assert np.asarray(why_1).any()  # episodes ended in the window compared
