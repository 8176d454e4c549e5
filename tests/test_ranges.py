"""A range that is accepted works: at the edges of every config range that shapes the road
and the traffic, the scripted controller still completes its lane changes; values beyond
them are refused with one message naming the key.

One compiled rollout serves every edge whose params differ only in traced values (the road's
curvature, lane width, speeds, inflow, ...); an edge that changes a static field (lane count,
slots, a curvature drawn per episode) compiles its own.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxlc import config
from jaxlc.sim.controller import scripted_action
from jaxlc.sim.env import EnvParams, LaneChangeEnv
from jaxlc.sim.reward import NO_GAP, REASONS

ENVS, STEPS = 32, 1500  # 150 s of 32 highways: ~60-300 lane changes per edge

# Each edge: overrides of the default config, alone or at a corner of several ranges.
EDGES = {
    "curvature min": ["env.curvature=-0.01"],
    "curvature max": ["env.curvature=0.01"],
    "curvature drawn over its range": ["env.curvature=[-0.01, 0.01]"],
    "lanes min, curved": ["env.lanes=2", "env.curvature=0.01"],
    "lanes max, curved": ["env.lanes=8", "env.curvature=-0.01"],
    "lane width min": ["env.lane_width=2.0"],
    "lane width max (= border)": ["env.lane_width=6.0", "env.border=6.0", "env.curvature=0.01"],
    "entry speed min": ["env.entry_speed_min=0.0", "env.entry_speed_max=0.0"],
    "entry speed max": ["env.entry_speed_min=200.0", "env.entry_speed_max=200.0"],
    "desired speed min": ["env.desired_speed_min=10.0", "env.desired_speed_max=10.0"],
    "desired speed max, curved": [
        "env.desired_speed_min=250.0",
        "env.desired_speed_max=250.0",
        "env.curvature=0.01",
    ],
    "inflow min": ["env.inflow_min=60.0", "env.inflow_max=60.0"],
    "inflow max, curved": ["env.inflow_min=4000.0", "env.inflow_max=4000.0", "env.curvature=-0.01"],
    "slots min": ["env.slots_per_lane=2"],
    "shortest road": ["env.road_length=451.0"],
    "sharpest, fastest, widest road": [
        "env.curvature=-0.01",
        "env.lanes=8",
        "env.desired_speed_min=250.0",
        "env.desired_speed_max=250.0",
    ],
}


@pytest.fixture(scope="module")
def run():
    """Jitted ``params -> (6,)`` counts of how RL manoeuvres ended (and episodes without a
    gap), the scripted controller driving ``ENVS`` envs for ``STEPS`` steps. Params are a
    traced argument: edges with the same static fields share one compile."""
    env = LaneChangeEnv()

    @jax.jit
    def counts(p: EnvParams) -> jax.Array:
        k_reset, k_run = jax.random.split(jax.random.PRNGKey(23))
        obs, state = jax.vmap(env.reset, (0, None))(jax.random.split(k_reset, ENVS), p)

        def body(c, key):
            obs, state = c
            keys = jax.random.split(key, ENVS)
            step = jax.vmap(env.step, (0, 0, 0, None))
            obs, state, _, _, _, info = step(keys, state, scripted_action(obs, p), p)
            ended = jnp.where(info["rl_step"] | (info["reason"] == NO_GAP), info["reason"], 0)
            return (obs, state), jnp.stack([jnp.sum(ended == i) for i in range(len(REASONS))])

        _, per_step = jax.lax.scan(body, (obs, state), jax.random.split(k_run, STEPS))
        return per_step.sum(0)

    return counts


@pytest.mark.parametrize("edge", EDGES)
def test_scripted_controller_completes_lane_changes_at_every_edge(run, edge):
    cfg = config.load(None, EDGES[edge])  # accepted: it is inside every range
    ends = dict(zip(REASONS, np.asarray(run(EnvParams.from_config(cfg.env))).tolist(), strict=True))
    performed = sum(ends[r] for r in ("success", "out_of_bounds", "collision", "timeout"))
    assert performed >= 30, ends  # the edge is exercised, not vacuous
    # Traffic may still cut one in (a collision); the controller must not run off or dawdle.
    assert ends["success"] >= 0.97 * performed, ends
    assert ends["out_of_bounds"] == 0, ends


@pytest.mark.parametrize(
    ("overrides", "words"),
    [
        (["env.curvature=0.011"], "'env.curvature': must be >= -0.01 and <= 0.01"),
        (["env.curvature=[-0.02, 0.0]"], "'env.curvature': must be >= -0.01 and <= 0.01"),
        (["env.curvature=[0.002, -0.002]"], "'env.curvature': a range [min, max] needs min"),
        (["env.curvature=[0.0, 0.001, 0.002]"], "'env.curvature': must be a number or a range"),
        (["env.lanes=9"], "'env.lanes': must be >= 2 and <= 8"),
        (["env.lane_width=4.0"], "'env.lane_width': must be <= env.border"),
        (["env.desired_speed_min=5.0"], "'env.desired_speed_min': must be >= 10"),
        (["env.inflow_min=30.0"], "'env.inflow_min': must be >= 60"),
        (["env.entry_speed_max=201.0"], "'env.entry_speed_max': must be >= 0 and <= 200"),
        (["ddpg.batch_size=63"], "'ddpg.batch_size': reflection pairs (ddpg.mirror_pairs"),
    ],
)
def test_values_that_cannot_work_are_refused_with_one_message(overrides, words):
    with pytest.raises(config.ConfigError) as err:
        config.load(None, overrides)
    message = str(err.value)
    assert words in message and "\n" not in message, message


@pytest.mark.slow
def test_pairs_need_mirrored_batches_and_nothing_else():
    """Reflection pairs are the default, and a batch without mirroring has nothing to pair:
    ``ddpg.mirror=false`` alone (the paper's batches, as the docs' commands spell them) loads
    and samples unpaired; an odd batch loads once the pairs are off."""
    from jaxlc.learn import replay
    from jaxlc.learn.networks import Actor, batch_actor

    assert config.load(None).ddpg.mirror_pairs
    plain = config.load(None, ["ddpg.mirror=false"])
    assert not plain.ddpg.mirror and plain.ddpg.mirror_pairs
    actor = Actor(mirror=(1.0, -1.0))
    assert batch_actor(actor, plain.ddpg) == actor.apply  # not the paired trunk pass
    rows = jnp.arange(12.0).reshape(6, 2)
    memory = replay.add(
        replay.init(8, 2, 1, 8),
        rows,
        rows[:, :1],
        rows[:, 0],
        rows,
        rows[:, 0] * 0,
        rows[:, 0] > -1,
    )
    key = jax.random.key(0)
    # train.py passes no reflection signs without ddpg.mirror, and the pairs flag then draws
    # the same batch as without it
    unpaired = replay.sample(memory, key, 4, None, None, False)
    for name, value in replay.sample(memory, key, 4, None, None, True).items():
        np.testing.assert_array_equal(value, unpaired[name])
    odd_batch = config.load(None, ["ddpg.batch_size=63", "ddpg.mirror_pairs=false"])
    assert odd_batch.ddpg.batch_size == 63


def test_a_curvature_range_round_trips_through_toml_and_keeps_straight_configs_alike(tmp_path):
    """``curvature = [min, max]`` is written and read back; a number stays a number, so the
    configs of straight roads (their hashes included) are those of before."""
    cfg = config.load(None, ["env.curvature=[-0.002, 0.002]"])
    assert cfg.env.curvature == (-0.002, 0.002)
    path = tmp_path / "c.toml"
    path.write_text(config.to_toml(cfg))
    assert config.load(path) == cfg and config.load(path).hash() == cfg.hash()
    straight = config.load(None)
    assert straight.env.curvature == 0.0 and isinstance(straight.env.curvature, float)
    p = EnvParams.from_config(cfg.env)
    assert p.curvature_drawn and (p.curvature_min, p.curvature_max) == (-0.002, 0.002)
    assert not EnvParams.from_config(straight.env).curvature_drawn
