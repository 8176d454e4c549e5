"""The fused trainer: grid under vmap, checkpoints, the sweep CLI, a real learning signal."""

import dataclasses
import importlib
import json
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxlc import config, sweep
from jaxlc.config import DDPGConfig
from jaxlc.learn import train, tree
from jaxlc.policy import actor_fn, load_policy
from jaxlc.sim.env import OBS_DIM
from jaxlc.sim.reward import NONE
from jaxlc.study import checkpoint

from .conftest import HANG_GUARD_S

SMOKE = config.CONFIG_DIR / "smoke.toml"


def _allclose_trees(a, b, rtol=1e-4, atol=1e-5):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol)


@pytest.mark.slow
def test_vmapped_model_equals_the_same_model_trained_alone(smoke_cfg):
    steps = 300  # egos reach the RL phase and the memory (batch 16) fills: updates run
    key = jax.random.PRNGKey(42)
    grid_state, _ = jax.jit(train.make_train(smoke_cfg), static_argnums=1)(key, steps)
    grid = train.make_grid(smoke_cfg)
    i = 2  # k=2, memory=256: not the largest memory, so its arrays are padded in the grid
    cell = grid.cells[grid.cell_of[i]]
    alone_cfg = config.load(SMOKE, [f"grid.k=[{cell['k']}]", f"grid.memory=[{cell['memory']}]"])
    alone, _ = jax.jit(train.make_train(alone_cfg), static_argnums=1)(key, steps)
    assert int(alone.learner.step[0]) > 0, "the test must cover updates"
    model_i = jax.tree.map(lambda a: a[i], grid_state.learner)
    model_0 = jax.tree.map(lambda a: a[0], alone.learner)
    _allclose_trees(model_i, model_0)
    assert int(grid_state.episodes[i]) == int(alone.episodes[0])
    # And the models of the grid really differ (k and memory are not ignored).
    other = jax.tree.map(lambda a: a[0], grid_state.learner)
    assert not np.allclose(
        np.asarray(jax.tree.leaves(other.actor)[0]), np.asarray(jax.tree.leaves(model_i.actor)[0])
    )


def test_grid_is_the_cartesian_product_with_seeds(smoke_cfg):
    cfg = config.load(SMOKE, ["train.seeds=2", "grid.actor_lr=[1e-4, 3e-4]"])
    grid = train.make_grid(cfg)
    assert grid.size == 2 * 2 * 2 * 2
    ks = np.asarray(grid.hyper.k)
    lrs = np.asarray(grid.hyper.ddpg.actor_lr)
    pairs = sorted(set(zip(ks.tolist(), (lrs * 1e4).round().astype(int).tolist(), strict=True)))
    assert pairs == [(1, 1), (1, 3), (2, 1), (2, 3)]
    assert grid.seeds == (0, 1) * 8


def test_a_seed_names_and_draws_the_same_model_whichever_seed_its_run_starts_from():
    six = config.load(SMOKE, ["train.seeds=6"])
    last3 = config.load(SMOKE, ["train.seeds=3", "train.seed=3"])
    g6, g3 = train.make_grid(six), train.make_grid(last3)
    cells = len(g6.cells)
    assert g3.seeds == (3, 4, 5) * cells  # the label a summary and a checkpoint path carry
    k6, k3 = np.asarray(train.model_keys(g6)), np.asarray(train.model_keys(g3))
    np.testing.assert_array_equal(k6[[s >= 3 for s in g6.seeds]], k3)
    # train.seed = 0 keeps the keys every committed study was trained with.
    root = jax.random.PRNGKey(0)
    want = [np.asarray(jax.random.fold_in(root, i % 6)) for i in range(g6.size)]
    np.testing.assert_array_equal(k6, np.stack(want))


def test_sweep_writes_checkpoints_metrics_and_summary(smoke_run, smoke_cfg):
    out, summary = smoke_run
    t = smoke_cfg.train
    grid = train.make_grid(smoke_cfg)
    ckpts = checkpoint.list_checkpoints(out)
    want = grid.size * (t.episodes // t.checkpoint_every)
    assert len(ckpts) == want
    metas = [json.loads(p.with_suffix(".json").read_text()) for p in ckpts]
    assert {(m["model"], m["episode"]) for m in metas} == {
        (i, e)
        for i in range(grid.size)
        for e in range(t.checkpoint_every, t.episodes + 1, t.checkpoint_every)
    }
    assert all(m["config_hash"] == smoke_cfg.hash() for m in metas)
    eps = np.load(out / "metrics" / "episodes.npz")
    assert (eps["episodes"] >= t.episodes).all()
    # Every logged episode ended for a reason, and RL episodes are at least one step long.
    assert (eps["reason"] != NONE).all() and (eps["steps"] >= 1).all()
    np.testing.assert_allclose(
        eps["ret"], eps["r_s"] + eps["r_e"] + eps["r_d"], rtol=1e-4, atol=1e-2
    )
    assert len(summary["models"]) == grid.size
    assert config.load(out / "config.toml").hash() == smoke_cfg.hash()


def test_checkpoint_loads_into_identical_params_and_actions(smoke_run, smoke_cfg):
    out, _ = smoke_run
    path = checkpoint.list_checkpoints(out)[-1]
    params, meta = checkpoint.load(path)
    # The final checkpoint of a model is the params it stopped learning with.
    grid = train.make_grid(smoke_cfg)
    assert meta["episode"] == smoke_cfg.train.episodes
    obs = jax.random.normal(jax.random.PRNGKey(0), (7, OBS_DIM))
    # The checkpoint records its network; load_policy builds the actor from that alone.
    assert tuple(meta["hidden"]) == tuple(smoke_cfg.ddpg.hidden) != DDPGConfig().hidden
    assert meta["symmetric_actor"] == smoke_cfg.ddpg.symmetric_actor
    act_loaded = load_policy(path)[0](obs)
    act_cfg = actor_fn(params, smoke_cfg.ddpg.hidden, smoke_cfg.ddpg.symmetric_actor)(obs)
    other = actor_fn(params, smoke_cfg.ddpg.hidden, not smoke_cfg.ddpg.symmetric_actor)(obs)
    assert not np.array_equal(np.asarray(other), np.asarray(act_cfg))
    np.testing.assert_array_equal(np.asarray(act_loaded), np.asarray(act_cfg))
    assert act_loaded.shape == (7, 1) and bool(jnp.all(jnp.abs(act_loaded) <= 1))
    # Saving the loaded params again gives the same bytes back.
    again = checkpoint.save(out / "copy.msgpack", params, meta)
    params2, _ = checkpoint.load(again)
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(params2), strict=True):
        np.testing.assert_array_equal(a, b)
    assert grid.size == 4


def test_sweep_refuses_a_run_dir_of_another_config(smoke_run, capsys):
    out, _ = smoke_run
    before = (out / "config.toml").read_text()
    rc = sweep.main(["--config", str(SMOKE), "--out", str(out), "train.episodes=20"])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another config" in err[0]
    assert (out / "config.toml").read_text() == before


@pytest.mark.parametrize(
    "override, words",
    [
        ("train.envs_per_model=0", "train.envs_per_model"),
        ("grid.k=[0]", "grid.k"),
        ("grid.memory=[8]", "batch_size"),
        ("grid.k=[]", "at least one"),
        ("ddpg.gamma=two", "must be a number"),
        ("env.no_such_key=1", "unknown config key 'env.no_such_key'"),
        ("train.noise_final=1.5", "train.noise_final': must be >= 0 and <= 1"),
        ("ddpg.learner=td3 ddpg.held_aware=true", "ddpg.held_aware': needs ddpg.learner"),
    ],
)
def test_bad_config_values_get_one_clear_line(override, words, capsys, tmp_path):
    rc = sweep.main(["--config", str(SMOKE), "--out", str(tmp_path / "r"), *override.split()])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert not (tmp_path / "r").exists()


def test_default_and_paper_tomls_spell_out_every_key():
    """configs/default.toml is the defaults written out and configs/paper.toml every key too,
    so the file a user reads is the study that runs."""
    assert config.load(config.DEFAULT_CONFIG) == config.Config()
    for path in (config.DEFAULT_CONFIG, config.PAPER_CONFIG):
        written = tomllib.loads(path.read_text())
        for table in dataclasses.fields(config.Config()):
            keys = {f.name for f in dataclasses.fields(getattr(config.Config(), table.name))}
            assert set(written[table.name]) == keys, (path.name, table.name)


def test_paper_toml_is_the_papers_method():
    """paper.toml: eq. (4)'s squared error, no mirroring, one update per RL transition; it
    differs from default.toml only in the learning aids and schedule the paper does not use."""
    paper, default = config.load(config.PAPER_CONFIG), config.Config()
    assert (
        paper.ddpg.huber_delta == 0.0 and not paper.ddpg.mirror and not paper.ddpg.symmetric_actor
    )
    assert paper.ddpg.updates_per_transition == 1
    assert paper.env.gap_min_ttc == 0.0
    changed = {
        (t.name, f.name)
        for t in dataclasses.fields(default)
        for f in dataclasses.fields(getattr(default, t.name))
        if getattr(getattr(paper, t.name), f.name) != getattr(getattr(default, t.name), f.name)
    }
    aids = ("huber_delta", "mirror", "mirror_pairs", "symmetric_actor", "tau")
    aids += ("updates_per_transition",)
    allowed = {("ddpg", k) for k in aids}
    assert changed <= allowed | {("env", "gap_min_ttc")}, changed


@pytest.mark.slow
def test_paper_schedule_makes_one_update_per_rl_transition(smoke_cfg):
    """``ddpg.updates_per_transition = 1`` (paper.toml): once the memory holds a batch, every
    scan step makes exactly as many updates as its envs gave RL transitions."""
    over = ["ddpg.updates_per_transition=1", "train.envs_per_model=16", "train.chunk_steps=50"]
    cfg = config.load(SMOKE, [*over, "grid.k=[1]", "grid.memory=[256]"])
    state, m = jax.jit(train.make_train(cfg), static_argnums=1)(jax.random.PRNGKey(3), 300)
    updates, transitions = np.asarray(m["updates"][:, 0]), np.asarray(m["transitions"][:, 0])
    filled = np.cumsum(transitions) >= cfg.ddpg.batch_size  # memory.size after the step's add
    assert filled.any() and (transitions[filled] > 1).any(), "the test must cover many envs"
    np.testing.assert_array_equal(updates, np.where(filled, transitions, 0))
    assert int(state.learner.step[0]) == updates.sum() > 0


def test_anneal_schedule_is_linear_from_its_start_and_off_by_default():
    h = train.ddpg.Hyper(
        actor_lr=jnp.float32(1e-4), critic_lr=jnp.float32(1e-3), noise_sigma=jnp.float32(0.2)
    )
    off = config.TrainConfig()  # the paper: constant noise and rates, unchanged bit for bit
    for ep in (0, 2500, 5000):
        same = train.anneal(h, jnp.int32(ep), off)
        pairs = zip(jax.tree.leaves(same), jax.tree.leaves(h), strict=True)
        assert all(np.array_equal(a, b) for a, b in pairs)
    t = config.TrainConfig(episodes=5000, anneal_from=0.5, noise_final=0.1, lr_final=0.2)
    # (episodes, multiplier of sigma, multiplier of the rates), worked by hand
    for ep, m_noise, m_lr in [(1000, 1.0, 1.0), (2500, 1.0, 1.0), (3750, 0.55, 0.6),
                              (5000, 0.1, 0.2), (7000, 0.1, 0.2)]:  # fmt: skip
        got = train.anneal(h, jnp.int32(ep), t)
        np.testing.assert_allclose(got.noise_sigma, 0.2 * m_noise, rtol=1e-6)
        np.testing.assert_allclose(got.actor_lr, 1e-4 * m_lr, rtol=1e-6)
        np.testing.assert_allclose(got.critic_lr, 1e-3 * m_lr, rtol=1e-6)


@pytest.mark.slow
def test_a_short_run_learns(smoke_cfg):
    """A real learning signal: the mean return of the last 100 of 400 episodes beats the first
    100 by a clear margin (settings that learn in seconds on this small task)."""
    cfg = config.load(
        SMOKE,
        [
            "train.episodes=400",
            "train.checkpoint_every=100",
            "ddpg.actor_lr=1e-3",
            "ddpg.updates_per_step=2",
            "grid.k=[1]",
            "grid.memory=[512]",
            "ddpg.hidden=[64, 64]",
            "train.envs_per_model=8",
        ],
    )
    grid = train.make_grid(cfg)
    init, run = train.make_grid_fns(cfg, grid)
    state = init(train.model_keys(grid))
    while int(state.episodes.min()) < cfg.train.episodes:
        state, _ = run(state, 500)
    ret = np.asarray(state.log.ret[0])
    first, last = ret[:100].mean(), ret[-100:].mean()
    assert last > first + 300.0, (first, last)


@pytest.mark.slow
def test_console_scripts_run_the_clis():
    """``[project.scripts]``: each name the install puts on the PATH runs its module's CLI."""
    scripts = tomllib.loads((config.CONFIG_DIR.parent / "pyproject.toml").read_text())["project"][
        "scripts"
    ]
    assert {"jaxlc-sweep", "jaxlc-evaluate", "jaxlc-figures"} <= set(scripts)
    for name, target in scripts.items():
        module, func = target.split(":")
        assert callable(getattr(importlib.import_module(module), func)), target
        if name in ("jaxlc-sweep", "jaxlc-evaluate"):
            exe = shutil.which(name, path=str(Path(sys.executable).parent))  # this venv's
            assert exe, f"{name} is not installed: pip install -e ."
            done = subprocess.run(
                [exe, "--help"], capture_output=True, text=True, timeout=HANG_GUARD_S
            )
            assert done.returncode == 0 and "usage:" in done.stdout, done.stderr[-2000:]


def test_tree_where_picks_whole_trees_or_rows():
    """``jaxlc.learn.tree.where``: a () mask picks one whole tree; a mask of leading axes picks
    row by row, broadcast over each leaf's trailing axes (leaves of different ranks)."""
    new = {"a": jnp.ones((3, 2)), "b": jnp.ones((3,), jnp.int32)}
    old = {"a": jnp.zeros((3, 2)), "b": jnp.zeros((3,), jnp.int32)}
    assert all(np.all(x == 1) for x in jax.tree.leaves(tree.where(jnp.bool_(True), new, old)))
    assert all(np.all(x == 0) for x in jax.tree.leaves(tree.where(jnp.bool_(False), new, old)))
    rows = tree.where(jnp.array([True, False, True]), new, old)
    np.testing.assert_array_equal(rows["a"], [[1, 1], [0, 0], [1, 1]])
    np.testing.assert_array_equal(rows["b"], [1, 0, 1])
    assert rows["b"].dtype == jnp.int32


def test_configs_of_studies_before_the_pairs_keep_their_batches():
    """The default draws reflection pairs (``ddpg.mirror_pairs``); the configs whose committed
    studies trained on rows reflected at random keep those batches, so their published
    numbers come from the config a user runs."""
    assert config.Config().ddpg.mirror_pairs
    for name in ("roads.toml", "joint.toml", "joint_assist.toml"):
        assert not config.load(config.CONFIG_DIR / name).ddpg.mirror_pairs, name
