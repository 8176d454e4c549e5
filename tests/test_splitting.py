"""Adaptive multilevel splitting (``jaxlc.evaluation.splitting``) on the +-1 random walk of
``benchmarks/ams_toy.py``, small: particles replay from their key chains, zero rounds is
crude MC on the same keys, a clone follows its parent to the branch, and the mean of many
cheap runs matches the closed form."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks import ams_toy
from jaxlc.evaluation import splitting as ams

STEPS, LEVEL = 20, 14  # P(max S_t >= 14 in 20 steps) = 1.49e-3
N, FRACTION, ROUNDS = 32, 0.25, 100
walk = functools.partial(ams_toy.walk, steps=STEPS)


@pytest.fixture(scope="module")
def programs():
    """The jitted programs every test shares: AMS (batched over keys) at ROUNDS and at 0
    rounds, and the walk of a batch of chains."""
    run = functools.partial(ams.splitting, walk, particles=N, kill_fraction=FRACTION)
    many = jax.jit(jax.vmap(functools.partial(run, max_rounds=ROUNDS), in_axes=(0, None)))
    none = jax.jit(functools.partial(run, max_rounds=0))
    return many, none, jax.jit(jax.vmap(walk))


def test_the_closed_form_is_the_walks_exact_probability():
    """Reflection principle against all 2^12 paths of a 12-step walk, at every level."""
    ups = (np.arange(2**12)[:, None] >> np.arange(12)) & 1  # (4096, 12) every path
    top = np.cumsum(2 * ups - 1, axis=1).max(axis=1)
    for a in range(1, 13):
        assert ams_toy.truth(12, a) == pytest.approx(np.mean(top >= a), rel=1e-12)
    assert ams_toy.truth(ams_toy.STEPS, ams_toy.LEVEL) == pytest.approx(1.8046e-9, rel=1e-4)


def test_a_final_particle_replays_bit_for_bit_from_its_chain(programs):
    many, _, walks = programs
    r = jax.device_get(many(jax.random.split(jax.random.key(3), 2), float(LEVEL)))
    assert (r.rounds > 0).all() and (r.chains.steps[..., 1:] < ams.UNUSED).any()  # clones
    for i in range(2):
        chains = jax.tree.map(lambda x, i=i: x[i], r.chains)
        again = np.asarray(walks(chains), np.float32)  # (N, T) from the chains alone
        np.testing.assert_array_equal(again, r.paths[i])
        np.testing.assert_array_equal(again.max(axis=1), r.scores[i])


def test_a_run_that_returns_its_steps_is_counted_and_splits_alike(programs):
    """``run`` returning ``(path, steps)``: ``env_steps`` sums every trajectory run, re-runs
    and chunk padding included (here each runs all STEPS), and nothing else changes."""
    many, _, _ = programs
    counted = jax.jit(jax.vmap(functools.partial(
        ams.splitting, lambda c: (walk(c), jnp.int32(STEPS)), particles=N,
        kill_fraction=FRACTION, max_rounds=ROUNDS), in_axes=(0, None)))  # fmt: skip
    keys = jax.random.split(jax.random.key(5), 2)
    a, b = jax.device_get(counted(keys, float(LEVEL))), jax.device_get(many(keys, float(LEVEL)))
    assert (a.rounds > 0).all() and (a.trajectories > N).all()
    np.testing.assert_array_equal(a.env_steps, a.trajectories * STEPS)
    np.testing.assert_array_equal(b.env_steps, 0)  # a path alone: no cost to count
    np.testing.assert_array_equal(a.estimate, b.estimate)
    np.testing.assert_array_equal(a.paths, b.paths)


SNAP = STEPS // 2  # the resumable walk's first snapshot: S before step SNAP


def walk_resumable(chain: ams.Chain, start=None, slots: int = 1):
    """``walk`` as a run with snapshots (``splitting``'s docstring), S before step SNAP and,
    with ``slots=2``, before the chain's last branch: ``(path, steps drawn, (at (slots,),
    S (slots,)))``, from ``start``'s snapshot where it is used (``at`` steps fewer)."""
    up = jax.vmap(jax.random.bernoulli)(ams.step_keys(chain, STEPS))
    inc = 2 * up.astype(jnp.int32) - 1
    at, base, first = jnp.int32(0), jnp.int32(0), jnp.int32(0)
    if start is not None:  # the parent's S before SNAP is this chain's when SNAP <= the branch
        use, j, (ats, values) = start
        at, base, first = jnp.where(use, ats[j], 0), jnp.where(use, values[j], 0), values[0]
    path = base + jnp.cumsum(jnp.where(jnp.arange(STEPS) >= at, inc, 0))  # right from at - 1
    used = chain.steps < ams.UNUSED
    branch = jnp.where(used.sum() > 1, jnp.max(jnp.where(used, chain.steps, 0)), ams.UNUSED)
    ats = jnp.asarray([SNAP, branch], jnp.int32)[:slots]
    values = jnp.stack([jnp.where(at > SNAP, first, path[SNAP - 1]), path[branch - 1]])[:slots]
    return path, STEPS - at, (ats, values)


def test_clones_resumed_from_their_parents_snapshot_split_alike_in_fewer_steps(programs):
    """A clone starts from its parent's latest snapshot before the branch: the run is the one
    that replays every clone from t = 0, bit for bit; with one snapshot each resumed clone
    draws SNAP steps fewer, and a second, at each clone's own branch, saves more."""
    many, _, _ = programs
    keys = jax.random.split(jax.random.key(5), 2)
    b = jax.device_get(many(keys, float(LEVEL)))
    one, two = (
        jax.device_get(jax.jit(jax.vmap(functools.partial(
            ams.splitting, functools.partial(walk_resumable, slots=slots), particles=N,
            kill_fraction=FRACTION, max_rounds=ROUNDS), in_axes=(0, None)))(keys, float(LEVEL)))
        for slots in (1, 2)
    )  # fmt: skip
    assert (one.resumed > 0).all() and (one.resumed < one.trajectories - N).all()  # some, not all
    np.testing.assert_array_equal(one.env_steps, one.trajectories * STEPS - one.resumed * SNAP)
    assert (two.env_steps < one.env_steps).all()
    for a in (one, two):
        np.testing.assert_array_equal(a.estimate, b.estimate)
        np.testing.assert_array_equal(a.paths, b.paths)
        np.testing.assert_array_equal(a.chains.keys, b.chains.keys)
    np.testing.assert_array_equal(b.resumed, 0)


def test_zero_rounds_is_crude_mc_on_the_same_first_keys(programs):
    """Nothing killed, nothing cloned: the estimate is the share of the initial particles
    at the target, and those are crude MC's walks on split(split(key)[0], N)."""
    _, none, _ = programs
    key = jax.random.key(7)
    level = 6.0  # low enough that some of 32 walks reach it
    r = none(key, level)
    first = jax.random.split(jax.random.split(key)[0], N)

    def crude(k):  # the walk written out again, step t keyed fold_in(k, t)
        up = jax.vmap(lambda t: jax.random.bernoulli(jax.random.fold_in(k, t)))(jnp.arange(STEPS))
        return jnp.cumsum(2 * up.astype(jnp.int32) - 1).max()

    hits = np.asarray(jax.vmap(crude)(first)) >= level
    assert 0 < hits.sum() < N
    assert int(r.rounds) == 0 and int(r.trajectories) == N
    assert float(r.estimate) == pytest.approx(hits.mean(), abs=1e-7)


def test_a_clone_follows_its_parent_to_the_branch_and_not_after(programs):
    _, _, walks = programs
    chains = ams.initial_chains(jax.random.key(11), 64, 4)
    paths = np.asarray(walks(chains), np.float32)  # (64, T)
    level = 1.0
    parent = np.flatnonzero(paths.max(axis=1) > level)[:8]  # (P,) above the level somewhere
    fresh = jax.random.key_data(jax.random.split(jax.random.key(12), parent.size))
    clones = ams.clone(chains, jnp.asarray(paths), jnp.asarray(parent), level, fresh)
    got = np.asarray(walks(clones))  # (P, T)
    for p, path in zip(parent, got, strict=True):
        tau = int(np.argmax(paths[p] > level))  # the parent's first step above the level
        np.testing.assert_array_equal(path[: tau + 1], paths[p, : tau + 1])
        assert tau + 1 < STEPS and (path[tau + 1 :] != paths[p, tau + 1 :]).any()


@pytest.mark.parametrize("rounds", [ROUNDS, 3])
def test_the_mean_of_many_cheap_runs_is_the_closed_form(programs, rounds):
    """Unbiased at 1.5e-3, and still when max_rounds stops it early (the martingale): the
    mean of 2000 runs of 32 particles within 4 standard errors of the truth."""
    many, _, _ = programs
    if rounds != ROUNDS:
        run = functools.partial(ams.splitting, walk, particles=N, kill_fraction=FRACTION)
        many = jax.jit(jax.vmap(functools.partial(run, max_rounds=rounds), in_axes=(0, None)))
    r = many(jax.random.split(jax.random.key(rounds), 2000), float(LEVEL))
    e = np.asarray(r.estimate, float)
    assert np.asarray(r.stopped).all() == (rounds == ROUNDS)
    p = ams_toy.truth(STEPS, LEVEL)
    se = e.std(ddof=1) / math.sqrt(e.size)
    assert se < 0.1 * p  # the check can tell a biased estimator at 10%
    assert abs(e.mean() - p) < 4 * se, (e.mean(), p, se)


def test_the_interval_is_students_t_over_the_runs():
    mean, lo, hi = ams.interval(np.array([1.0, 2.0, 3.0, 4.0]))
    assert mean == 2.5 and hi - mean == pytest.approx(3.182446 * math.sqrt(5 / 3) / 2, rel=1e-6)
    assert lo == pytest.approx(2.5 - (hi - 2.5))
    assert ams.interval(np.array([1e-9, 1e-6]))[1] == 0.0  # clipped at 0
    assert all(type(v) is float for v in ams.interval(np.arange(3.0)))  # for summary.json


def test_the_exceedance_curve_ends_at_the_estimate(programs):
    """One run's curve P(score > Z_j) = prod_{i<=j} (1 - K_i / N) falls with the level, and
    its last value times the share at the target is the estimate."""
    many, _, _ = programs
    r = jax.device_get(many(jax.random.split(jax.random.key(5), 1), float(LEVEL)))
    one = jax.tree.map(lambda x: x[0], r)
    levels = np.asarray(one.levels[: one.rounds])
    probs = np.cumprod(1.0 - np.asarray(one.kills[: one.rounds]) / N)
    assert levels.size == one.rounds > 0 and (np.diff(levels) > 0).all()  # ties all killed
    assert (np.diff(probs) < 0).all() and levels[-1] < LEVEL
    assert probs[-1] * one.reached == pytest.approx(float(one.estimate), rel=1e-5)


def test_the_curve_at_every_level_is_unbiased(programs):
    """``exceedance_at``: at the target it is the run's estimate; over 2000 runs its mean at
    each level a = 6, 8, 10, 12 of the walk is the closed form P(max >= a) within 4 standard
    errors (a between two of a run's levels included)."""
    many, _, _ = programs
    r = jax.device_get(many(jax.random.split(jax.random.key(11), 2000), float(LEVEL)))
    at = np.asarray([6.0, 8.0, 10.0, 12.0, float(LEVEL)])
    runs = [jax.tree.map(lambda x, i=i: x[i], r) for i in range(2000)]
    e = np.asarray([ams.exceedance_at(one, N, at) for one in runs])  # (runs, levels)
    np.testing.assert_allclose(e[:, -1], np.asarray(r.estimate), rtol=1e-5)
    for j, a in enumerate(at):
        p, se = ams_toy.truth(STEPS, int(a)), e[:, j].std(ddof=1) / math.sqrt(len(runs))
        assert abs(e[:, j].mean() - p) < 4 * se, (a, e[:, j].mean(), p, se)


def test_the_log_interval_covers_a_skewed_mean_where_t_misses_low():
    """4000 samples of 10 lognormal draws (sigma 0.6, the skew of a product of many
    factors): Cox's interval covers the mean about 95%, Student's t about 91%."""
    x = np.random.default_rng(0).lognormal(0.0, 0.6, (4000, 10))
    mu = math.exp(0.6**2 / 2)
    cover = {
        log: np.mean([lo <= mu <= hi for _, lo, hi in (ams.interval(r, log=log) for r in x)])
        for log in (False, True)
    }
    assert cover[True] == pytest.approx(0.95, abs=0.01) and cover[False] < 0.93, cover
    assert ams.interval(np.array([0.0, 1.0, 2.0]), log=True) == ams.interval(np.arange(3.0))


# On the simulator (jaxlc.evaluation.ams): the smoke config's scripted controller, few
# particles (cases, split from their reset on). The particles, kill and rounds of
# tests/test_validate.py's ``--method ams`` and validate's step cap: one AMS program and one
# reset program serve both files (on one worker, or loaded from the suite's compilation cache
# on the other).
SIM_N, SIM_KILL, SIM_ROUNDS, SIM_STEPS, SIM_CAP = 12, 0.25, 4, 1500, 2.6


@pytest.fixture(scope="module")
def sim():
    """The cases, the policy, the AMS program at SIM_ROUNDS and at 0 rounds (one compile
    each), and the engine's crude-MC program of the validation on the same keys."""
    from jaxlc import config
    from jaxlc.evaluation import ams as sim_ams
    from jaxlc.evaluation import keys, validation

    cfg = config.load(config.CONFIG_DIR / "smoke.toml")
    cs = sim_ams.starts(cfg, SIM_N, 0, 0)
    pol = validation.policies(cfg, None, 1)
    one = jax.tree.map(lambda x: x[0], pol)
    prog = {
        r: sim_ams.program(cfg, "collision", SIM_N, SIM_KILL, r, SIM_STEPS) for r in (0, SIM_ROUNDS)
    }
    crude = validation.program(cfg, SIM_STEPS, False)
    out, _ = crude(None, pol, keys.stream(0, keys.VALIDATE, range(SIM_N)))
    return dict(cfg=cfg, cs=cs, pol=one, prog=prog, out=jax.device_get(out))


@pytest.mark.slow
def test_a_case_particle_replays_bit_for_bit_from_its_chain(sim):
    from jaxlc.evaluation import ams as sim_ams

    prog = sim["prog"][SIM_ROUNDS]
    res = jax.device_get(prog(jax.random.PRNGKey(3), sim["pol"], sim["cs"], 0.0, SIM_CAP))
    assert int(res.rounds) >= 1  # particles were killed and cloned
    steps = np.asarray(res.chains.steps)
    cloned = np.sum(steps != ams.UNUSED, axis=1) >= 2
    assert cloned.any() and int(res.resumed) >= 1  # some clones began at a parent's snapshot
    # every final particle run again from its chain, by the program ``ams.replay`` runs a miss on
    replay = sim_ams._case_program(sim["cfg"], "collision", SIM_STEPS, False)
    again = np.asarray(replay(sim["pol"], sim["cs"], SIM_CAP, res.chains))
    np.testing.assert_array_equal(again, np.asarray(res.paths))
    assert (again.max(axis=1) == res.scores).all()
    # the approach scores below -cap: only a lane change's margin reaches above it
    lane_change = np.asarray(sim["out"]["performed"][0])
    assert (res.first[~lane_change] <= -SIM_CAP).all()


@pytest.mark.slow
def test_noise_acts_on_the_manoeuvres_actions_alone_and_replays(sim):
    """``--noise``: the training's exploration noise on each action, drawn from the step's
    key: a case with no lane change keeps its path bit for bit, lane changes mostly do not, and
    a clone branched where its parent's noise first told keeps the parent's path up to there
    and draws noise of its own after."""
    from jaxlc.evaluation import ams as sim_ams

    chains = ams.initial_chains(jax.random.PRNGKey(0), SIM_N, 2)  # one segment in force
    chains = chains.replace(keys=chains.keys.at[:, 0].set(sim["cs"].key))
    plain = sim_ams._case_program(sim["cfg"], "collision", SIM_STEPS, False)  # replay's
    run = {0: plain, 0.3: sim_ams._case_program(sim["cfg"], "collision", SIM_STEPS, False, 0.3)}
    paths = {n: np.asarray(r(sim["pol"], sim["cs"], SIM_CAP, chains)) for n, r in run.items()}
    lane_change = np.asarray(sim["out"]["performed"][0])
    assert lane_change.any() and not lane_change.all()
    np.testing.assert_array_equal(paths[0.3][~lane_change], paths[0][~lane_change])
    moved = (paths[0.3] != paths[0]).any(axis=1)  # a margin may be set before the noise tells
    assert moved[lane_change].mean() > 0.5
    branch = np.where(moved, np.argmax(paths[0.3] != paths[0], axis=1), ams.UNUSED)
    fresh = jax.random.key_data(jax.random.split(jax.random.PRNGKey(1), SIM_N))
    clones = chains.replace(steps=chains.steps.at[:, 1].set(branch),
                            keys=chains.keys.at[:, 1].set(fresh))  # fmt: skip
    again = np.asarray(run[0.3](sim["pol"], sim["cs"], SIM_CAP, clones))
    for i in np.flatnonzero(moved):
        np.testing.assert_array_equal(again[i, : branch[i]], paths[0.3][i, : branch[i]])
    np.testing.assert_array_equal(again[~moved], paths[0.3][~moved])
    assert (again[moved] != paths[0.3][moved]).any(axis=1).mean() > 0.5


@pytest.mark.slow
def test_no_rounds_is_the_engines_crude_mc_on_the_same_keys(sim):
    """max_rounds = 0 keeps the first particles: each case's margin (where below the cap) is
    the one the validation's own rollout (jaxlc.evaluation.engine) folds on the same case
    keys, so the estimate at every margin below the cap is crude MC's share per case."""
    out, cs = sim["out"], sim["cs"]
    engine = np.where(out["performed"][0], out["margin_gap"][0], np.inf)  # (SIM_N,)
    assert len(engine) == SIM_N and out["performed"][0].sum() >= SIM_N // 2
    res = jax.device_get(sim["prog"][0](jax.random.PRNGKey(0), sim["pol"], cs, 0.0, 50.0))
    below = engine < 50.0
    np.testing.assert_allclose(-np.asarray(res.first)[below], engine[below], rtol=1e-6)
    assert (-np.asarray(res.first)[~below] >= 50.0).all()  # the approach: at most -cap
    for m in np.quantile(engine[below], [0.25, 0.5, 0.75]):
        est = sim["prog"][0](jax.random.PRNGKey(0), sim["pol"], cs, -float(m), 50.0).estimate
        assert float(est) == np.float32(np.mean(engine <= m)) > 0  # in float32


@pytest.mark.slow
def test_the_default_cap_leaves_the_border_and_time_to_the_lane_change(sim):
    """Without --span the cap is m + SPAN for collisions (the approach foretells the gap) and
    above every lane change's border and time margin for the others, so no approach score
    (<= -cap) outranks the lane change's own margin; a given span is m + span."""
    from jaxlc.evaluation import ams as sim_ams
    from jaxlc.evaluation.measures import MARGINS
    from jaxlc.sim.env import EnvParams

    out, p = sim["out"], EnvParams.from_config(sim["cfg"].env)
    lane_change = np.asarray(out["performed"][0])
    assert sim_ams.cap_of(p, "collision", 1.0, None) == pytest.approx(1.0 + sim_ams.SPAN)
    for kind in ("out_of_bounds", "timeout"):
        margins = np.asarray(out[MARGINS[kind]][0])[lane_change]
        assert (margins > 1.0 + sim_ams.SPAN).any()  # a cap of m + SPAN would sit below them
        assert (margins < sim_ams.cap_of(p, kind, 1.0, None)).all()
        assert sim_ams.cap_of(p, kind, 1.0, 0.3) == pytest.approx(1.3)


@pytest.mark.parametrize(
    "bad",
    [["--particles", "1"], ["--kill", "1.0"], ["--repeats", "1"], ["--margin", "-1"],
     ["--kind", "failure"], ["--max-rounds", "-1"], ["--span", "0"], ["--chain", "2"],
     ["--noise", "1.5"], ["--noise", "-0.1"], ["--noise", "0.2", "--method", "mc"]],
)  # fmt: skip
def test_a_bad_ams_argument_is_one_line_and_exit_2(bad, tmp_path, capsys):
    from jaxlc import validate

    assert validate.main([str(tmp_path), "--method", "ams", *bad]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: --"), err
