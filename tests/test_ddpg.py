"""DDPG update against a hand-written reference of eqs. (4)-(7); exploration; vmap; benchmark."""

import dataclasses
import math
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxlc import config
from jaxlc.config import DDPGConfig
from jaxlc.learn import ddpg, learners
from jaxlc.learn.networks import Actor, make_networks
from jaxlc.sim.observation import INDEX, MIRROR_SIGNS
from jaxlc.sim.observation import OBS_DIM as FULL_OBS

OBS_DIM = 5
# a big final init and tau so that every term of the update moves the params visibly
# huber_delta=0: the paper's squared error of eq. (4); the Huber option and the symmetric
# actor have their own tests
CFG = dataclasses.replace(
    DDPGConfig(),
    hidden=(4, 3),
    batch_size=8,
    final_init=0.5,
    tau=0.1,
    huber_delta=0.0,
    symmetric_actor=False,
)
HYPER = ddpg.Hyper(jnp.float32(3e-2), jnp.float32(5e-2), jnp.float32(0.2))


def _batch(seed, n=CFG.batch_size, obs_dim=OBS_DIM):
    """Host-side data: jax.random here would cost a compile per shape."""
    rng = np.random.default_rng(seed)
    f32 = np.float32
    return {
        "obs": rng.normal(size=(n, obs_dim)).astype(f32),
        "action": rng.uniform(-1, 1, (n, 1)).astype(f32),
        "reward": rng.normal(size=n).astype(f32),
        "next_obs": rng.normal(size=(n, obs_dim)).astype(f32),
        "terminated": (rng.random(n) < 0.3).astype(f32),
    }


_init = jax.jit(lambda key: ddpg.init_learner(key, OBS_DIM, CFG))


def _learner(seed):
    """A learner whose targets differ from the online nets, so eqs. (6)/(7) are visible."""
    learner = jax.device_get(_init(jax.random.key(seed)))
    shift = lambda p: jax.tree.map(lambda x: x + 0.1 * np.sin(7 * x + 1), p)  # noqa: E731
    return learner.replace(actor_target=shift(learner.actor), critic_target=shift(learner.critic))


def _stack(trees):
    return jax.tree.map(lambda *x: np.stack(x), *trees)


# ---- independent reference: plain MLPs, jax.grad, the Adam formula in numpy ----------------


def _mlp(params, x):
    layers = params["params"]["mlp"]
    for i in range(len(layers)):
        x = x @ layers[f"Dense_{i}"]["kernel"] + layers[f"Dense_{i}"]["bias"]
        x = jax.nn.relu(x) if i < len(layers) - 1 else x
    return x


def _q(params, s, a):
    return _mlp(params, jnp.concatenate([s, a], -1))[:, 0]


def _mu(params, s):
    return jnp.tanh(_mlp(params, s))


def _adam(p, g, m, v, t, lr, b1=0.9, b2=0.999, eps=1e-8):
    """Adam (Kingma & Ba, optax's defaults) on pytrees: (params, m, v) after step t (1-based)."""
    m = jax.tree.map(lambda m, g: b1 * m + (1 - b1) * np.asarray(g), m, g)
    v = jax.tree.map(lambda v, g: b2 * v + (1 - b2) * np.asarray(g) ** 2, v, g)
    step = lambda p, m, v: p - lr * (m / (1 - b1**t)) / (np.sqrt(v / (1 - b2**t)) + eps)  # noqa: E731
    return jax.tree.map(step, p, m, v), m, v


@jax.jit
def _reference_grads(a, c, at, ct, batch):
    """Critic loss and the gradients of eqs. (4) and (5) by jax.grad on plain MLPs."""
    s, act = batch["obs"], batch["action"]
    y = batch["reward"] + CFG.gamma * (1 - batch["terminated"]) * _q(
        ct, batch["next_obs"], _mu(at, batch["next_obs"])
    )  # eq. (4) target
    critic_loss = lambda cp: jnp.mean((y - _q(cp, s, act)) ** 2)  # noqa: E731 eq. (4)
    actor_loss = lambda ap: -jnp.mean(_q(c, s, _mu(ap, s)))  # noqa: E731 eq. (5)
    loss, gc = jax.value_and_grad(critic_loss)(c)
    return loss, gc, jax.grad(actor_loss)(a)


def _reference_update(state, batch, t):
    """state: (actor, critic, actor_t, critic_t, {"a": (m, v), "c": (m, v)}); t: 1-based step."""
    a, c, at, ct, mom = state
    loss, gc, ga = _reference_grads(a, c, at, ct, batch)
    a2, *mom_a = _adam(a, ga, *mom["a"], t, float(HYPER.actor_lr))
    c2, *mom_c = _adam(c, gc, *mom["c"], t, float(HYPER.critic_lr))
    soft = lambda tp, p: jax.tree.map(lambda x, y: CFG.tau * y + (1 - CFG.tau) * x, tp, p)  # noqa: E731
    return (a2, c2, soft(at, a2), soft(ct, c2), {"a": mom_a, "c": mom_c}), float(loss)


@pytest.mark.slow
def test_flax_modules_match_plain_mlps_and_final_init():
    learner = _learner(9)
    actor, critic = make_networks(CFG)
    batch = _batch(9)
    s, a = batch["obs"], batch["action"]
    _close(actor.apply(learner.actor, s), _mu(learner.actor, s))
    _close(critic.apply(learner.critic, s, a), _q(learner.critic, s, a))
    for params in (learner.actor, learner.critic):
        head = params["params"]["mlp"][f"Dense_{len(CFG.hidden)}"]
        for leaf in (head["kernel"], head["bias"]):
            assert np.abs(leaf).max() <= CFG.final_init and np.abs(leaf).max() > 0


@pytest.mark.slow
def test_symmetric_actor_is_odd_under_the_road_reflection():
    """ddpg.symmetric_actor: same params as the plain actor, mu(Ms) = -mu(s), and the value is
    the reference (f(s) - f(Ms)) / 2; a state its own mirror image (nothing lateral) gets 0."""
    cfg = dataclasses.replace(CFG, symmetric_actor=True)
    plain, _ = make_networks(CFG)
    sym, _ = make_networks(cfg)
    x = np.zeros((1, FULL_OBS), np.float32)
    params = sym.init(jax.random.key(3), x)
    assert jax.tree.structure(params) == jax.tree.structure(plain.init(jax.random.key(3), x))
    params = jax.tree.map(lambda p: p * 40.0, params)  # leave tanh's linear range
    s = np.random.default_rng(3).normal(size=(16, FULL_OBS)).astype(np.float32)
    m = s * np.asarray(MIRROR_SIGNS, np.float32)
    a, a_m = np.asarray(sym.apply(params, s)), np.asarray(sym.apply(params, m))
    np.testing.assert_array_equal(a_m, -a)
    _close(a, 0.5 * (_mu(params, s) - _mu(params, m)))
    assert np.abs(a).max() > 0.1 and np.abs(np.asarray(plain.apply(params, s)) - a).max() > 0.01
    own_image = np.where(np.asarray(MIRROR_SIGNS) < 0, 0.0, s).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(sym.apply(params, own_image)), 0.0)


@pytest.mark.slow
def test_the_paired_actor_reads_f_of_ms_off_the_batch():
    """``Actor.paired`` on a batch [s; Ms] equals the odd actor on the same rows (one trunk
    pass instead of two: rounding may differ), mu(Ms) = -mu(s) exactly; a plain actor's
    ``paired`` is its ``__call__``; and an update on a paired batch with ``mirror_pairs`` on
    equals the update with it off (same losses and params within float32 rounding)."""
    cfg = dataclasses.replace(CFG, symmetric_actor=True, mirror=True, mirror_pairs=True)
    sym, _ = make_networks(cfg)
    params = jax.tree.map(
        lambda p: p * 40.0, sym.init(jax.random.key(4), np.zeros((1, FULL_OBS), np.float32))
    )
    s = np.random.default_rng(4).normal(size=(16, FULL_OBS)).astype(np.float32)
    pair = np.concatenate([s, s * np.asarray(MIRROR_SIGNS, np.float32)])
    paired = np.asarray(sym.apply(params, pair, method=Actor.paired))
    np.testing.assert_allclose(paired, np.asarray(sym.apply(params, pair)), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(paired[16:], -paired[:16])
    assert np.abs(paired).max() > 0.1
    plain, _ = make_networks(CFG)
    np.testing.assert_array_equal(
        np.asarray(plain.apply(params, pair, method=Actor.paired)), plain.apply(params, pair)
    )
    learner = ddpg.init_learner(jax.random.key(5), FULL_OBS, cfg)
    rng = np.random.default_rng(5)
    half = {
        "obs": s,
        "action": rng.uniform(-1, 1, (16, 1)).astype(np.float32),
        "reward": rng.normal(size=16).astype(np.float32),
        "next_obs": rng.normal(size=(16, FULL_OBS)).astype(np.float32),
        "terminated": np.zeros(16, np.float32),
    }
    sign = {"obs": MIRROR_SIGNS, "next_obs": MIRROR_SIGNS, "action": (-1.0,)}
    batch = {
        k: np.concatenate([v, v * np.asarray(sign.get(k, 1.0), np.float32)])
        for k, v in half.items()
    }
    hyper = ddpg.Hyper.from_config(cfg)
    off = dataclasses.replace(cfg, mirror_pairs=False)
    (new_on, m_on), (new_off, m_off) = (ddpg.update(learner, batch, hyper, c) for c in (cfg, off))
    _close(m_on, m_off)
    _close(new_on.actor, new_off.actor)
    _close(new_on.critic, new_off.critic)


@pytest.fixture(scope="module")
def update_fn():
    return jax.jit(lambda lrn, b, h: ddpg.update(lrn, b, h, CFG))


def _close(x, y):
    for u, v in zip(jax.tree.leaves(x), jax.tree.leaves(y), strict=True):
        np.testing.assert_allclose(np.asarray(u), np.asarray(v), rtol=2e-5, atol=2e-6)


@pytest.mark.slow
def test_update_matches_reference_of_eqs_4_to_7(update_fn):
    learner = _learner(0)
    zeros = lambda p: jax.tree.map(np.zeros_like, p)  # noqa: E731
    state = (
        learner.actor,
        learner.critic,
        learner.actor_target,
        learner.critic_target,
        {"a": (zeros(learner.actor),) * 2, "c": (zeros(learner.critic),) * 2},
    )
    for t in range(1, 4):
        batch = _batch(t)
        learner, metrics = update_fn(learner, batch, HYPER)
        state, loss = _reference_update(state, batch, t)
        _close(learner.actor, state[0])
        _close(learner.critic, state[1])
        _close(learner.actor_target, state[2])
        _close(learner.critic_target, state[3])
        assert math.isclose(float(metrics["critic_loss"]), loss, rel_tol=1e-5)
        q = _q(state[1], batch["obs"], batch["action"])  # sanity: the metric is a mean Q
        assert np.isfinite(float(metrics["mean_q"])) and np.isfinite(float(q.mean()))
    assert int(learner.step) == 3


def test_update_moves_every_param(update_fn):
    learner = _learner(2)
    new, _ = update_fn(learner, _batch(3), HYPER)
    for old, upd in [
        (learner.actor, new.actor),
        (learner.critic, new.critic),
        (learner.actor_target, new.actor_target),
    ]:
        for u, v in zip(jax.tree.leaves(old), jax.tree.leaves(upd), strict=True):
            assert np.any(np.asarray(u) != np.asarray(v))


@pytest.mark.slow
def test_huber_critic_loss_is_squared_inside_delta_and_linear_beyond(update_fn):
    """``ddpg.huber_delta``: TD errors within delta cost their square as in eq. (4); beyond
    it the cost grows linearly (2*delta*|e| - delta^2), so an outlier pulls the critic with
    the force of an error of delta. A delta above every error gives eq. (4)'s update."""
    learner, batch = _learner(6), _batch(6)
    batch["reward"] = batch["reward"] * np.float32(40.0)  # errors on both sides of delta
    c, at, ct = learner.critic, learner.actor_target, learner.critic_target
    y = batch["reward"] + CFG.gamma * (1 - batch["terminated"]) * _q(
        ct, batch["next_obs"], _mu(at, batch["next_obs"])
    )
    e = np.abs(np.asarray(y - _q(c, batch["obs"], batch["action"])))
    delta = float(np.median(e))
    assert (e < delta).any() and (e > delta).any()
    huber = jax.jit(lambda lrn, b, h, d: ddpg.update(lrn, b, h, d), static_argnums=3)
    _, m = huber(learner, batch, HYPER, dataclasses.replace(CFG, huber_delta=delta))
    want = np.mean(np.where(e <= delta, e**2, 2 * delta * e - delta**2))
    assert math.isclose(float(m["critic_loss"]), want, rel_tol=1e-5)
    wide, m_wide = huber(learner, batch, HYPER, dataclasses.replace(CFG, huber_delta=1e6))
    squared, m_sq = update_fn(learner, batch, HYPER)
    assert math.isclose(float(m_wide["critic_loss"]), float(m_sq["critic_loss"]), rel_tol=1e-6)
    _close(wide.critic, squared.critic)


def test_vmapped_update_equals_each_model_alone(update_fn):
    learners = _stack([_learner(4 + m) for m in range(3)])
    batches = _stack([_batch(10 + m) for m in range(3)])
    hyper = ddpg.Hyper(
        np.float32([1e-3, 1e-2, 5e-2]), np.float32([2e-3, 3e-2, 1e-1]), np.float32([0.2] * 3)
    )
    grid = jax.jit(jax.vmap(lambda lrn, b, h: ddpg.update(lrn, b, h, CFG)))(
        learners, batches, hyper
    )
    grid = jax.device_get(grid)  # slice on the host: eager slicing compiles a program per leaf
    for m in range(3):
        one = lambda x, m=m: x[m]  # noqa: E731
        alone = update_fn(*jax.tree.map(one, (learners, batches, hyper)))
        _close(jax.tree.map(one, grid), alone)
    kernels = grid[0].actor["params"]["mlp"]["Dense_0"]["kernel"]
    assert not np.allclose(kernels[0], kernels[2])  # the lrs did differ


def test_held_aware_bootstraps_on_the_held_action_and_teaches_the_actor_where_it_acts():
    """ddpg.held_aware: y = r + gamma (1 - d) Q'(s', a') with a' = mu'(s') only where s'
    refreshes the action, the held one (obs "held") elsewhere; the actor's loss averages
    -Q(s, mu(s)) over the states that refresh it. Checked against the plain MLPs."""
    cfg = dataclasses.replace(CFG, held_aware=True)
    learner = jax.device_get(
        jax.jit(lambda k: ddpg.init_learner(k, FULL_OBS, cfg))(jax.random.key(5))
    )
    batch = {
        **_batch(6, obs_dim=FULL_OBS),
        "refresh": np.float32([[1, 0], [0, 1], [1, 0], [0, 0], [1, 1], [0, 0], [1, 0], [0, 1]]),
    }
    _, metrics = jax.jit(lambda lrn, b: ddpg.update(lrn, b, HYPER, cfg))(learner, batch)
    s, s2, ref = batch["obs"], batch["next_obs"], batch["refresh"]
    mu2 = _mu(learner.actor_target, s2)  # (n, 1)
    a2 = np.where(ref[:, 1:] > 0, mu2, s2[:, INDEX["held"], None])
    assert not np.allclose(a2, mu2)  # the held actions differ from the target actor's
    y = batch["reward"] + cfg.gamma * (1 - batch["terminated"]) * _q(learner.critic_target, s2, a2)
    critic = np.mean((y - _q(learner.critic, s, batch["action"])) ** 2)
    q_mu = _q(learner.critic, s, _mu(learner.actor, s))
    actor = -np.sum(ref[:, 0] * q_mu) / np.sum(ref[:, 0])
    assert math.isclose(float(metrics["critic_loss"]), float(critic), rel_tol=1e-5)
    assert math.isclose(float(metrics["actor_loss"]), float(actor), rel_tol=1e-5)


def test_explore_truncates_noise_and_stays_in_bounds():
    sigma = 0.05
    zero = jnp.zeros((20000, 1))
    noisy = jax.jit(ddpg.explore, static_argnums=3)(jax.random.key(6), zero, sigma, 2.0)
    noise = np.asarray(noisy)
    assert np.abs(noise).max() <= 2.0 * sigma * (1 + 1e-6)
    assert np.abs(noise).max() > 1.9 * sigma  # truncated, not shrunk
    assert 0.7 * sigma < noise.std() < sigma
    edge = jnp.concatenate([jnp.full((5000, 1), 0.99), jnp.full((5000, 1), -0.99)])
    sigmas = jnp.asarray([0.0, 0.5, 2.0])  # traced per model, as in the grid
    out = np.asarray(
        jax.vmap(ddpg.explore, in_axes=(0, None, 0))(
            jax.random.split(jax.random.key(7), 3), edge, sigmas
        )
    )
    assert out.min() >= -1.0 and out.max() <= 1.0
    np.testing.assert_array_equal(out[0], np.asarray(edge))
    assert np.any(out[2] == 1.0) and np.any(out[2] == -1.0)


@pytest.mark.slow
def test_benchmark_tiny_runs(tmp_path):
    from benchmarks import update_throughput as bench

    out = tmp_path / "tiny.csv"
    figures = bench.main(["--tiny", "--out", str(out)])
    for name in (
        "peak_gflops",
        "grid_updates_per_s",
        "achieved_gflops",
        "share_of_peak",
        "share_of_peak_best_of",
        "update_ms",
        "products_alone_ms",
        "products_alone_share_of_peak",
        "optimizer_alone_ms",
        "optimizer_alone_gbps",
        "stream_gbps",
        "share_ceiling",
    ):
        assert math.isfinite(figures[name]) and figures[name] > 0, name
    assert out.read_text().count("\n") == 2


def _dot_flops(jaxpr) -> int:
    """2 x multiply-adds of every dot_general in a jaxpr, sub-jaxprs included."""
    total = 0
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            (contract, _), _ = eqn.params["dimension_numbers"]
            lhs = eqn.invars[0].aval.shape
            total += 2 * math.prod(eqn.outvars[0].aval.shape) * math.prod(lhs[d] for d in contract)
        for value in eqn.params.values():
            for sub in value if isinstance(value, tuple | list) else (value,):
                if hasattr(sub, "eqns"):
                    total += _dot_flops(sub)
                elif hasattr(sub, "jaxpr") and hasattr(sub.jaxpr, "eqns"):
                    total += _dot_flops(sub.jaxpr)
    return total


@pytest.mark.parametrize("symmetric, pairs", [(False, False), (True, False), (True, True)])
def test_benchmark_counts_the_products_that_the_update_computes(symmetric, pairs):
    """The benchmark's FLOP count against the dot_generals in the traced ``ddpg.update`` at
    the paper's sizes. JAX also forms the first critic layer's input gradient for the
    observation columns (the benchmark counts only the action columns, the ones the actor
    needs): 2 x 64 x 300 x 14 FLOPs, 0.2% of the update. On paired batches the odd actor's
    update costs the plain actor's."""
    cfg, obs_dim, batch = DDPGConfig(symmetric_actor=symmetric, mirror_pairs=pairs), 14, 64
    learner = jax.eval_shape(lambda k: ddpg.init_learner(k, obs_dim, cfg), jax.random.key(0))
    data = {
        "obs": jnp.zeros((batch, obs_dim)),
        "action": jnp.zeros((batch, 1)),
        "reward": jnp.zeros(batch),
        "next_obs": jnp.zeros((batch, obs_dim)),
        "terminated": jnp.zeros(batch),
    }
    traced = jax.make_jaxpr(lambda lrn: ddpg.update(lrn, data, ddpg.Hyper.from_config(cfg), cfg))
    in_update = _dot_flops(traced(learner).jaxpr)
    from benchmarks import update_throughput as bench

    counted = bench.matmul_flops(
        bench.update_products(obs_dim, cfg.hidden, batch, 1, cfg.symmetric_actor, cfg.mirror_pairs)
    )
    assert in_update - counted == 2 * batch * cfg.hidden[0] * obs_dim
    if pairs:
        plain = bench.matmul_flops(bench.update_products(obs_dim, cfg.hidden, batch))
        assert counted == plain


# ---- TD3, the option -------------------------------------------------------------------

TD3 = dataclasses.replace(CFG, learner="td3", td3_target_noise=0.0, td3_policy_delay=2)


@pytest.fixture(scope="module")
def td3_fns():
    algo = learners.of(TD3)
    init = jax.jit(lambda key: algo.init_learner(key, OBS_DIM, TD3))
    update = jax.jit(lambda lrn, b, h, k: algo.update(lrn, b, h, TD3, key=k))
    return init, update


def test_the_config_accepts_exactly_the_learners_there_are() -> None:
    assert config.CHOICES["ddpg.learner"] == tuple(learners.LEARNERS)
    for name, module in learners.LEARNERS.items():
        for attr in ("Hyper", "Learner", "init_learner", "update", "explore"):
            assert callable(getattr(module, attr)), f"{name} lacks {attr}"
    with pytest.raises(config.ConfigError, match="ddpg.learner': must be one of 'ddpg', 'td3'"):
        config.load(None, ["ddpg.learner='sac'"])
    # runs written before the key: ddpg.td3 = true reads as the TD3 learner
    assert config.from_dict({"ddpg": {"td3": True}}).ddpg.learner == "td3"
    assert config.from_dict({"ddpg": {"td3": False}}).ddpg.learner == "ddpg"
    cfg = config.load(None, ["ddpg.learner='td3'"])
    assert config.from_dict(tomllib.loads(config.to_toml(cfg))).ddpg.learner == "td3"


def test_td3_regresses_twins_on_the_smaller_target_and_delays_the_actor(td3_fns):
    init, update = td3_fns
    learner = jax.device_get(init(jax.random.key(3)))
    twins = [jax.tree.map(lambda x, i=i: x[i], learner.critic) for i in range(2)]
    assert not np.allclose(
        twins[0]["params"]["mlp"]["Dense_0"]["kernel"],
        twins[1]["params"]["mlp"]["Dense_0"]["kernel"],
    ), "the twins must start apart"
    batch = _batch(3)
    s, a, s2 = batch["obs"], batch["action"], batch["next_obs"]
    # With no target noise, y = r + gamma (1 - d) min_i Q'_i(s', mu'(s')).
    targets = [jax.tree.map(lambda x, i=i: x[i], learner.critic_target) for i in range(2)]
    a2 = _mu(learner.actor_target, s2)
    y = batch["reward"] + TD3.gamma * (1 - batch["terminated"]) * np.minimum(
        _q(targets[0], s2, a2), _q(targets[1], s2, a2)
    )
    want = sum(float(np.mean((y - _q(c, s, a)) ** 2)) for c in twins)
    key = jax.random.key(0)
    new, metrics = update(learner, batch, HYPER, key)
    np.testing.assert_allclose(float(metrics["critic_loss"]), want, rtol=1e-5)

    # step 0: actor and both targets move; step 1: only the critics do.
    def moved(x, y):
        pairs = zip(jax.tree.leaves(x), jax.tree.leaves(y), strict=True)
        return not all(np.array_equal(u, v) for u, v in pairs)

    assert moved(new.actor, learner.actor) and moved(new.critic_target, learner.critic_target)
    newer, _ = update(jax.device_get(new), batch, HYPER, key)
    assert moved(newer.critic, new.critic)
    assert not moved(newer.actor, new.actor)
    assert not moved(newer.actor_target, new.actor_target)
    assert not moved(newer.critic_target, new.critic_target)
