"""The whole training run as pure functions: DDPG and the simulator in one ``lax.scan``.

    train = make_train(config)            # PureJaxRL style
    state, metrics = train(key, steps)    # every model of the grid, vmapped, in one program

A *model* is one cell of the grid (k, memory, learning rates, noise) with one seed; all models
share shapes, so the grid is a ``vmap`` over a leading ``(models,)`` axis of one ``TrainState``.
Each scan step, for every model: the actor (plus truncated-normal noise) acts in all of the
model's parallel envs; the transitions of envs whose ego is under RL control go into the
replay memory; once it holds a batch, DDPG updates follow (``updates_per_step`` per scan step,
or ``updates_per_transition`` per RL transition, the paper's schedule); episodes that
ended are appended to a per-model episode log; when the episode count passes a multiple of
``checkpoint_every`` the actor is copied to a snapshot slot the host saves between chunks.
A model stops learning (its params freeze) once it has done ``train.episodes`` episodes, so
its last checkpoint is exactly the params at that episode.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from jaxlc.config import Config, ConfigError, DDPGConfig, TrainConfig
from jaxlc.learn import ddpg, learners, replay, tree
from jaxlc.learn.networks import make_networks
from jaxlc.sim.ego import refreshes
from jaxlc.sim.env import ACTION_MIRROR, EnvParams, EnvState, LaneChangeEnv, action_dim
from jaxlc.sim.observation import MIRROR_SIGNS, OBS_DIM
from jaxlc.sim.reward import SUCCESS
from jaxlc.sim.reward import names as reward_names


@flax.struct.dataclass
class ModelHyper:
    """Per-model values that differ across the grid, traced (``(models,)`` under vmap)."""

    ddpg: ddpg.Hyper
    k: Array  # () int32 action-update step
    capacity: Array  # () int32 replay memory size


@flax.struct.dataclass
class EpisodeLog:
    """One row per finished RL episode, in order of completion: ``(max_episodes,)`` each."""

    ret: Array  # total reward
    steps: Array  # manoeuvre steps (int32)
    reason: Array  # jaxlc.sim.reward reason code (int32)
    terms: dict[str, Array]  # each reward term's sum over the episode, by name (env.reward_terms)
    at_step: Array  # scan step at which it ended (int32)
    # The terms' order (a pytree's dict comes back with its keys sorted).
    names: tuple[str, ...] = flax.struct.field(pytree_node=False, default=())

    def columns(self) -> dict[str, Array]:
        """Every column by name, the terms' in their order: what ``metrics/episodes.npz``
        holds."""
        terms = {n: self.terms[n] for n in self.names}
        return {"ret": self.ret, "steps": self.steps, "reason": self.reason, **terms} | {
            "at_step": self.at_step
        }


@flax.struct.dataclass
class TrainState:
    """Everything a model needs to continue; a ``(models, ...)`` stack of these is the run."""

    learner: ddpg.Learner
    memory: replay.Replay
    env: EnvState  # (envs,)
    obs: Array  # (envs, OBS_DIM)
    terms: Array  # (envs, reward terms) running sums of the current manoeuvre's terms
    key: Array
    step: Array  # () int32 scan steps done
    episodes: Array  # () int32 RL episodes finished
    log: EpisodeLog
    snap_actor: Any  # actor params at the last checkpoint episode passed
    snap_episode: Array  # () int32 that episode (0 = none yet)


@flax.struct.dataclass
class Grid:
    """The models of a run: ``hyper`` stacked ``(models,)`` plus host-side descriptions."""

    hyper: ModelHyper
    cells: tuple[dict[str, Any], ...] = flax.struct.field(pytree_node=False)
    seeds: tuple[int, ...] = flax.struct.field(pytree_node=False)  # seed per model
    cell_of: tuple[int, ...] = flax.struct.field(pytree_node=False)  # cell index per model

    @property
    def size(self) -> int:
        return len(self.cell_of)


def grid_cells(cfg: Config) -> tuple[dict[str, Any], ...]:
    """Cartesian product of the grid axes, k outermost. Plain Python, so a CLI can size the
    grid before JAX starts (``machine.use_host_devices``)."""
    g, d = cfg.grid, cfg.ddpg
    axes = {
        "k": g.k,
        "memory": g.memory,
        "actor_lr": g.actor_lr or (d.actor_lr,),
        "critic_lr": g.critic_lr or (d.critic_lr,),
        "noise_sigma": g.noise_sigma or (d.noise_sigma,),
    }
    return tuple(
        dict(zip(axes, values, strict=True)) for values in itertools.product(*axes.values())
    )


def make_grid(cfg: Config) -> Grid:
    """The grid's cells (``grid_cells``) times ``train.seeds`` seeds: ``train.seed``,
    ``train.seed + 1``, ... So ``train.seed=3 --seeds 3`` trains the last three models of
    ``--seeds 6``, and a model's seed names it in every table and file."""
    cells = grid_cells(cfg)
    first = cfg.train.seed
    models = [(c, s) for c in range(len(cells)) for s in range(first, first + cfg.train.seeds)]

    def col(name: str, dtype: Any) -> Array:
        return jnp.asarray([cells[c][name] for c, _ in models], dtype)

    hyper = ModelHyper(
        ddpg=ddpg.Hyper(
            actor_lr=col("actor_lr", jnp.float32),
            critic_lr=col("critic_lr", jnp.float32),
            noise_sigma=col("noise_sigma", jnp.float32),
        ),
        k=col("k", jnp.int32),
        capacity=col("memory", jnp.int32),
    )
    return Grid(
        hyper=hyper,
        cells=cells,
        seeds=tuple(s for _, s in models),
        cell_of=tuple(c for c, _ in models),
    )


def model_keys(grid: Grid) -> Array:
    """``(models,)`` keys, ``fold_in(PRNGKey(0), seed)``: models with the same seed share
    initial params and traffic (common random numbers make the grid's comparisons sharper),
    and a seed trains the same model whichever ``train.seed`` its run started from."""
    return _seed_keys(jax.random.PRNGKey(0), grid)


def _seed_keys(root: Array, grid: Grid) -> Array:
    return jnp.stack([jax.random.fold_in(root, s) for s in grid.seeds])


def _empty_log(n: int, terms: tuple[str, ...]) -> EpisodeLog:
    f, i = jnp.zeros((n,), jnp.float32), jnp.zeros((n,), jnp.int32)
    return EpisodeLog(
        ret=f, steps=i, reason=i, terms={t: f for t in terms}, at_step=i, names=tuple(terms)
    )


def _log_add(log: EpisodeLog, start: Array, ended: Array, rows: dict[str, Array]) -> EpisodeLog:
    """Append the rows of envs with ``ended`` at ``start, start+1, ...``; rows past the log's
    end are dropped (a model's last step may finish more episodes than it needs)."""
    take = ended.astype(jnp.int32)
    slot = jnp.where(ended, start + jnp.cumsum(take) - take, log.ret.shape[0])

    def put(column: Array, value: Array) -> Array:
        return column.at[slot].set(value.astype(column.dtype), mode="drop")

    terms = {n: put(log.terms[n], rows[n]) for n in log.terms}
    rest = {n: put(getattr(log, n), v) for n, v in rows.items() if n not in log.terms}
    return log.replace(terms=terms, **rest)


def anneal(h: ddpg.Hyper, episodes: Array, t: TrainConfig) -> ddpg.Hyper:
    """Per-model noise sigma and learning rates after ``episodes`` finished episodes: scaled
    linearly from 1 at ``t.anneal_from`` of ``t.episodes`` to ``t.noise_final`` /
    ``t.lr_final`` at the last episode. The paper's constants are ``noise_final = lr_final =
    1`` (the default), which leaves every value unchanged bit for bit."""
    start = t.anneal_from * t.episodes
    frac = jnp.clip((episodes - start) / max(t.episodes - start, 1.0), 0.0, 1.0)
    lr = 1.0 - (1.0 - t.lr_final) * frac
    return ddpg.Hyper(
        actor_lr=h.actor_lr * lr,
        critic_lr=h.critic_lr * lr,
        noise_sigma=h.noise_sigma * (1.0 - (1.0 - t.noise_final) * frac),
    )


def init_model(key: Array, hyper: ModelHyper, cfg: Config) -> TrainState:
    """ONE model's fresh state: ``train.envs_per_model`` roads after warm-up, a new learner,
    an empty memory of ``hyper.capacity`` transitions."""
    d, t = cfg.ddpg, cfg.train
    base = EnvParams.from_config(cfg.env, gamma=d.gamma)
    k_learn, k_env, k_run = jax.random.split(key, 3)
    keys = jax.random.split(k_env, t.envs_per_model)
    obs, env_state = jax.vmap(LaneChangeEnv().reset, (0, None))(keys, base)
    learner = learners.of(d).init_learner(k_learn, OBS_DIM, d, action_dim(base))
    return TrainState(
        learner=learner,
        memory=replay.init(
            max(cfg.grid.memory), OBS_DIM, action_dim(base), hyper.capacity, d.held_aware
        ),
        env=env_state,
        obs=obs,
        terms=jnp.zeros((t.envs_per_model, len(base.reward_terms)), jnp.float32),
        key=k_run,
        step=jnp.int32(0),
        episodes=jnp.int32(0),
        log=_empty_log(t.episodes, reward_names(base)),
        snap_actor=learner.actor,
        snap_episode=jnp.int32(0),
    )


def _learn(
    learner: ddpg.Learner,
    memory: replay.Replay,
    key: Array,
    h: ddpg.Hyper,
    d: DDPGConfig,
    updating: Array,
    transitions: Array,
) -> tuple[ddpg.Learner, dict[str, Array], Array]:
    """DDPG updates on batches from ``memory``, kept only when ``updating``: returns the
    learner, the losses of the last update ``(1,)`` and the count of updates made.

    ``d.updates_per_transition = 0``: ``d.updates_per_step`` updates every scan step.
    Otherwise that many per RL transition of this step (``transitions``, the model's envs
    together), the paper's one update per environment step of its single env."""

    algo = learners.of(d)

    def one_update(learner: ddpg.Learner, k: Array):
        batch = replay.sample(
            memory,
            k,
            d.batch_size,
            MIRROR_SIGNS if d.mirror else None,
            ACTION_MIRROR[: memory.action.shape[-1]],
            d.mirror_pairs,
        )
        return algo.update(learner, batch, h, d, key=jax.random.fold_in(k, 1))

    if d.updates_per_transition == 0:
        keys = jax.random.split(key, d.updates_per_step)
        new, losses = jax.lax.scan(one_update, learner, keys)
        made = jnp.where(updating, d.updates_per_step, 0).astype(jnp.int32)
        return tree.where(updating, new, learner), jax.tree.map(lambda x: x[-1:], losses), made

    n = jnp.where(updating, transitions * d.updates_per_transition, 0).astype(jnp.int32)
    shapes = jax.eval_shape(one_update, learner, key)[1]
    nan = jax.tree.map(lambda s: jnp.full((1,) + s.shape, jnp.nan, s.dtype), shapes)

    def body(c: tuple) -> tuple:
        i, lrn, _ = c
        lrn, losses = one_update(lrn, jax.random.fold_in(key, i))
        return i + 1, lrn, jax.tree.map(lambda x: x[None], losses)

    _, new, losses = jax.lax.while_loop(lambda c: c[0] < n, body, (jnp.int32(0), learner, nan))
    return new, losses, n


def _step_metrics(
    updating: Array,
    losses: dict[str, Array],
    rl: Array,
    ended: Array,
    info: dict[str, Array],
    obs: Array,
    reward: Array,
) -> dict[str, Array]:
    """One scan step's metrics of one model (scalars); losses are NaN while not updating."""
    return {
        "critic_loss": jnp.where(updating, losses["critic_loss"][-1], jnp.nan),
        "actor_loss": jnp.where(updating, losses["actor_loss"][-1], jnp.nan),
        "mean_q": jnp.where(updating, losses["mean_q"][-1], jnp.nan),
        "transitions": rl.sum(dtype=jnp.int32),
        "episodes_ended": ended.sum(dtype=jnp.int32),
        "successes": (ended & (info["reason"] == SUCCESS)).sum(dtype=jnp.int32),
        # False from the first step that produced a non-finite loss, reward or observation.
        "finite": (~updating | jnp.all(jnp.stack([jnp.isfinite(v[-1]) for v in losses.values()])))
        & jnp.all(jnp.isfinite(obs))
        & jnp.all(jnp.isfinite(reward)),
    }


def make_model_fns(cfg: Config) -> tuple[Callable, Callable]:
    """``init(key, hyper) -> TrainState`` and ``step(state, hyper) -> (state, metrics)`` for
    ONE model; the grid vmaps them."""
    env = LaneChangeEnv()
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    d, t = cfg.ddpg, cfg.train
    n_envs, every = t.envs_per_model, t.checkpoint_every
    actor_net, _ = make_networks(d, action_dim(base))

    def step(ts: TrainState, hyper: ModelHyper) -> tuple[TrainState, dict[str, Array]]:
        key, k_noise, k_env, k_update = jax.random.split(ts.key, 4)
        learning = ts.episodes < t.episodes
        h = anneal(hyper.ddpg, ts.episodes, t)

        # Act in every env; only RL-phase steps are transitions.
        mu = actor_net.apply(ts.learner.actor, ts.obs)  # (envs, action_dim)
        action = learners.of(d).explore(k_noise, mu, h.noise_sigma, d.noise_clip)
        obs, env_state, reward, term, trunc, info = jax.vmap(env.step, (0, 0, 0, None))(
            jax.random.split(k_env, n_envs), ts.env, action, base.replace(k=hyper.k)
        )
        rl = info["rl_step"]  # (envs,)
        refresh = None
        if d.held_aware:  # the step refreshed the action at s; will s' refresh it
            n = info["episode_steps"]  # (envs,) RL steps taken, this one included
            refresh = jnp.stack([refreshes(n - 1, hyper.k), refreshes(n, hyper.k)], -1)
        memory = replay.add(
            ts.memory,
            ts.obs,
            info["action"].reshape(n_envs, -1),  # (envs, action_dim)
            reward,
            obs,
            term.astype(jnp.float32),
            rl,
            refresh,
        )

        # DDPG updates once the memory holds one batch [P]/[S].
        updating = learning & (memory.size >= d.batch_size)
        transitions = rl.sum(dtype=jnp.int32)
        learner, losses, updates = _learn(ts.learner, memory, k_update, h, d, updating, transitions)

        # Episode bookkeeping; the snapshot slot keeps the actor of the last checkpoint passed.
        names = reward_names(base)
        terms = ts.terms + jnp.stack([info[n] for n in names], -1)  # (envs, reward terms)
        ended = rl & (term | trunc) & learning
        rows = {
            "ret": info["episode_return"],
            "steps": info["episode_steps"],
            "reason": info["reason"],
            **{n: terms[:, i] for i, n in enumerate(names)},
            "at_step": jnp.full((n_envs,), ts.step),
        }
        episodes = ts.episodes + ended.sum(dtype=jnp.int32)
        passed = (episodes // every) > (ts.episodes // every)
        ts = TrainState(
            learner=learner,
            memory=memory,
            env=env_state,
            obs=obs,
            terms=jnp.where((rl & (term | trunc))[:, None], 0.0, terms),
            key=key,
            step=ts.step + 1,
            episodes=episodes,
            log=_log_add(ts.log, ts.episodes, ended, rows),
            snap_actor=tree.where(passed, learner.actor, ts.snap_actor),
            snap_episode=jnp.where(
                passed, jnp.minimum(episodes // every * every, t.episodes), ts.snap_episode
            ),
        )
        metrics = _step_metrics(updating & (updates > 0), losses, rl, ended, info, obs, reward)
        return ts, {**metrics, "updates": updates}

    def init(key: Array, hyper: ModelHyper) -> TrainState:
        return init_model(key, hyper, cfg)

    return init, step


def check_devices(n: int, error: type[Exception] = ConfigError) -> None:
    """Raise ``error`` unless ``1 <= n <=`` the devices JAX sees (``--devices`` of the sweep
    and of evaluation)."""
    if not 1 <= n <= len(jax.devices()):
        raise error(
            f"--devices: must be between 1 and {len(jax.devices())} (the devices JAX sees), got {n}"
        )


def make_grid_fns(
    cfg: Config, grid: Grid, devices: Sequence[jax.Device] | None = None
) -> tuple[Callable, Callable]:
    """Jitted ``init(keys) -> state`` and ``run(state, steps) -> (state, metrics)`` over the
    whole grid; state leaves are ``(models, ...)``, metrics leaves ``(steps, models)``.

    With several ``devices`` the models axis is laid over a 1-D mesh (``shard_map``): each
    device runs its block of models, with no communication between them. The model count is
    padded to a multiple of the device count with copies of the last model, and the padding
    is dropped from everything returned, so callers never see it.
    """
    init, step = make_model_fns(cfg)
    m = grid.size
    devices = list(devices) if devices else jax.devices()[:1]
    pad = -m % len(devices)

    def pad_rows(tree: Any) -> Any:
        if not pad:
            return tree
        return jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, 0)]), tree)

    hyper = pad_rows(grid.hyper)
    shard: Callable = lambda f, out_specs: f  # noqa: E731 - one device: plain vmap
    if len(devices) > 1:
        mesh = Mesh(np.asarray(devices), ("models",))
        # check_vma off: the env's warm-up scan starts from unsharded constants, and every
        # value here is per-model anyway (no collectives to check).
        shard = partial(jax.shard_map, mesh=mesh, in_specs=P("models"), check_vma=False)

    @jax.jit
    def v_init(keys: Array) -> TrainState:
        state = shard(jax.vmap(init), out_specs=P("models"))(pad_rows(keys), hyper)
        return jax.tree.map(lambda a: a[:m], state)

    @partial(jax.jit, static_argnames="steps")
    def run(state: TrainState, steps: int) -> tuple[TrainState, dict[str, Array]]:
        def blocks(s: TrainState, h: ModelHyper):
            return jax.lax.scan(lambda c, _: jax.vmap(step)(c, h), s, None, length=steps)

        state, metrics = shard(blocks, out_specs=(P("models"), P(None, "models")))(
            pad_rows(state), hyper
        )
        return jax.tree.map(lambda a: a[:m], state), jax.tree.map(lambda a: a[:, :m], metrics)

    return v_init, run


def make_train(cfg: Config) -> Callable[[Array, int], tuple[TrainState, dict[str, Array]]]:
    """``train(key, steps)``: init every model of the grid from ``key`` (its seed folded in;
    ``PRNGKey(0)`` gives the sweep's models) and run ``steps`` scan steps; one pure, jittable
    function."""
    grid = make_grid(cfg)
    init, step = make_model_fns(cfg)

    def train(key: Array, steps: int) -> tuple[TrainState, dict[str, Array]]:
        state = jax.vmap(init)(_seed_keys(key, grid), grid.hyper)
        return jax.lax.scan(lambda s, _: jax.vmap(step)(s, grid.hyper), state, None, length=steps)

    return train
