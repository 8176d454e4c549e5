"""``jaxlc.validate`` and its estimators (``jaxlc.evaluation.rare``): the toy check of the IS
interval's coverage, weights of 1 under the nominal proposal, the command on a smoke run."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxlc import config
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation import rare


def test_tilts_at_the_nominal_give_weight_one():
    v = jax.random.uniform(jax.random.PRNGKey(0), (1000,))
    p = jnp.float32(0.003)
    u = rare.tilt_bernoulli(v, p, p)
    assert np.all(np.asarray(rare.bernoulli_log_ratio(u, p, p)) == 0.0)
    assert np.allclose(np.asarray(u), np.asarray(v), atol=1e-6)
    u = rare.tilt_exponential(v, jnp.float32(0.0))
    assert np.all(np.asarray(u) == np.asarray(v))
    assert np.all(np.asarray(rare.exponential_log_ratio(u, jnp.float32(0.0))) == 0.0)


def test_exponential_tilt_is_a_density():
    """Under the tilt, the mean weight is 1 and the CE fit recovers theta."""
    v = jax.random.uniform(jax.random.PRNGKey(1), (200_000,))
    u = rare.tilt_exponential(v, jnp.float32(3.0))
    w = np.exp(np.asarray(rare.exponential_log_ratio(u, jnp.float32(3.0)), np.float64))
    assert abs(w.mean() - 1.0) < 0.02
    assert abs(rare.exponential_fit(float(np.mean(u))) - 3.0) < 0.1


@pytest.mark.slow
def test_toy_interval_covers_the_truth():
    """100 independent repeats of the final IS stage with one CE-fitted proposal: the 95%
    interval covers the closed-form 8.4e-7 in at least 93 (the full check with CE in each
    repeat: the retired benchmarks/scripts/validate_toy.py at b98c04d)."""
    q = rare.toy_estimate(jax.random.PRNGKey(7), 1000)["q"]
    keys = jax.random.split(jax.random.PRNGKey(8), 100)
    sample = jax.jit(jax.vmap(lambda k: rare.toy_sample(k, 20_000, q)))
    truth, est = rare.toy_truth(), []
    for i in range(0, 100, 10):
        log_w, events = (np.asarray(a) for a in sample(keys[i : i + 10]))
        est += [rare.is_estimate(a, e >= rare.TOY_K) for a, e in zip(log_w, events, strict=True)]
    assert sum(r["lo"] <= truth <= r["hi"] for r in est) >= 93
    assert sum(r["mean_weight_lo"] <= 1.0 <= r["mean_weight_hi"] for r in est) >= 90


def test_mc_estimate_is_clopper_pearson():
    r = rare.mc_estimate(0, 3_000_000)
    assert r["estimate"] == 0.0 and r["rel_halfwidth"] == math.inf
    assert r["upper_bound"] == pytest.approx(1e-6, rel=0.01)
    r = rare.mc_estimate(200, 1_000_000)
    assert r["lo"] < 2e-4 < r["hi"] and 0.1 < r["rel_halfwidth"] < 0.2


# The command on a smoke run, in the traffic that brakes (the tilt's own draws included).
TRAFFIC = ["env.braking=true", "env.braking_rate=200", "env.gap_min_ttc=0"]
# Cases per program: the fixture's and the nominal test's, so one program serves both; fewer
# than ``cases.SPILL_MIN_BATCH``, so the program runs each phase as one loop (at 64 the fixture
# took 37 s, its program compiling both phases twice over; 23 s at 63, whose cases hold as
# many failures: one, a timeout, in 99 lane changes against 100).
CHUNK = 63
SHARE = 0.5  # the fixture's defensive mixture: its second chunk drawn from the nominal


@pytest.fixture(scope="module")
def validated(smoke_run, tmp_path_factory):
    """A smoke run validated by IS (scripted controller, every failure kind's cases kept)."""
    from jaxlc import validate

    run_dir, _ = smoke_run
    out = tmp_path_factory.mktemp("validate")
    args = ["--model", "scripted", "--method", "is", "--kind", "failure", "--chunk", str(CHUNK)]
    args += ["--lane-changes", "60", "--defensive", str(SHARE), "--out", str(out)]
    args += ["--traffic", *TRAFFIC]
    assert validate.main([str(run_dir), *args]) == 0
    return run_dir, out


def test_validate_writes_its_outputs(validated):
    import json

    from jaxlc.evaluation import validation

    _, out = validated
    doc = json.loads((out / "validate.json").read_text())
    (model,) = doc["models"]
    assert model["lane_changes"] >= 60 and model["ce"]
    # the defensive mixture's nominal chunks, in the share asked
    chunks = model["cases_started"] // CHUNK
    nominal = sum(validation.nominal_chunk(i, SHARE) for i in range(chunks))
    assert chunks > 1 and model["defensive"] == nominal / chunks > 0
    assert set(model["estimates"]) == set(validation.KINDS)
    e = model["estimates"]["failure"]
    assert e["lo"] <= e["estimate"] <= e["hi"]
    assert "braking events" in doc["traffic"] and doc["matmul_peak_gflops"] > 0
    assert (out / "validate.csv").is_file() and (out / "validate.md").is_file()
    # the fixture's traffic fails the scripted controller: its failures are kept, and each
    # failing kind's scene is drawn from a replay
    assert json.loads((out / "cases.json").read_text())
    assert (out / "scenes.png").is_file()


def test_replay_reproduces_a_case_bit_for_bit(validated):
    import json

    from jaxlc.evaluation.validation_io import replay_case

    run_dir, out = validated
    cases = json.loads((out / "cases.json").read_text())
    assert cases, "the smoke validation's traffic fails the scripted controller"
    path, same = replay_case(run_dir, 0, out)
    assert same and path.stat().st_size > 0
    # each case names its mixture component in the proposal that replays it
    assert all(c["proposal"]["drawn_nominal"] == float(c["drawn_nominal"]) for c in cases)


def test_nominal_proposal_weights_are_one(smoke_run):
    """The proposal equal to the traffic's own distribution: every log weight exactly 0."""
    from jaxlc.evaluation import proposal, validation
    from jaxlc.evaluation.cases import columns
    from jaxlc.evaluation.heldout import in_traffic
    from jaxlc.sim.env import EnvParams
    from jaxlc.study.rundir import RunDir

    cfg = in_traffic(RunDir(smoke_run[0]).load_config(), TRAFFIC)
    base = EnvParams.from_config(cfg.env)
    # the validated fixture's program (``validate``'s default step cap): loaded, not compiled
    run = validation.program(cfg, config.EvalConfig().max_steps, True)
    keys = streams.stream(0, streams.VALIDATE, range(CHUNK))
    trials = []
    for start in range(len(proposal.TILT_FROM)):
        nom = proposal.nominal(base).replace(tilt_from=jnp.float32(start))
        out = columns(jax.device_get(run(nom, validation.policies(cfg, None, 1), keys)[0]))
        assert out["performed"].any() and np.all(out["log_w"] == 0.0)
        # (cases,) braking trials counted, every role
        trials.append(out["tilt"][0][:, : len(proposal.ROLES)].sum(axis=1))
    assert trials[0].sum() > 0  # braking trials around the ego were drawn
    # the same cases (nominal draws): a tilt that starts earlier counts every trial a later
    # one does, and more where the ego cruised or searched before its lane change
    assert np.all(trials[0] <= trials[1]) and np.all(trials[1] <= trials[2])
    assert trials[0].sum() < trials[1].sum() < trials[2].sum()


def test_a_nominal_chunk_drives_the_traffics_own_draws_weighed_against_the_proposal(smoke_run):
    """The defensive mixture's nominal share (``drawn_nominal``): the same lane changes as the
    traffic's own draws, each weighed by the ratio of its braking draws against the proposal
    (which tilts the target lane's lead alone): ``events log(p/q) + (trials - events)
    log((1-p)/(1-q))`` of the lead's, as in a chunk the proposal draws."""
    from jaxlc.evaluation import proposal, validation
    from jaxlc.evaluation.cases import columns
    from jaxlc.evaluation.heldout import in_traffic
    from jaxlc.sim.braking import start_probability
    from jaxlc.sim.env import EnvParams
    from jaxlc.study.rundir import RunDir

    cfg = in_traffic(RunDir(smoke_run[0]).load_config(), TRAFFIC)
    base = EnvParams.from_config(cfg.env)
    run = validation.program(cfg, config.EvalConfig().max_steps, True)  # the fixture's
    keys = streams.stream(0, streams.VALIDATE, range(CHUNK))
    nom, p, q = proposal.nominal(base), float(start_probability(base)), 0.02
    tilt = nom.replace(brake=nom.brake.at[proposal.ROLES.index("lead")].set(q))
    props = {"nominal": nom, "own": tilt.replace(drawn_nominal=jnp.float32(1.0)), "tilt": tilt}
    pol = validation.policies(cfg, None, 1)
    out = {n: columns(jax.device_get(run(pr, pol, keys)[0])) for n, pr in props.items()}
    for field in ("performed", "reason", "steps"):
        assert np.array_equal(out["own"][field], out["nominal"][field])
    col = {s: proposal.STATS.index(f"brake_{s}_lead") for s in ("trials", "events")}
    for name in ("own", "tilt"):
        perf, st = out[name]["performed"][0], out[name]["tilt"][0].astype(np.float64)
        trials, events = st[:, col["trials"]], st[:, col["events"]]
        expect = events * math.log(p / q) + (trials - events) * math.log((1 - p) / (1 - q))
        assert trials[perf].sum() > 0
        np.testing.assert_allclose(out[name]["log_w"][0][perf], expect[perf], rtol=1e-4, atol=1e-4)
    events = {n: out[n]["tilt"][0][:, col["events"]].sum() for n in ("own", "tilt")}
    assert events["tilt"] > events["own"]  # the proposal's lead brakes more often


def test_the_mixtures_nominal_chunks_keep_their_share_and_cap_the_weights():
    from jaxlc.evaluation import validation

    for alpha in (0.0, 0.2, 0.5, 0.7):
        flags = [validation.nominal_chunk(i, alpha) for i in range(100)]
        assert not flags[0] and sum(flags) == round(100 * alpha)
        assert all(abs(sum(flags[:n]) - n * alpha) < 1 for n in range(1, 101))
    log_r = np.array([-50.0, -1.0, 0.0, 3.0, 50.0])
    w = np.exp(rare.defensive(log_r, 0.5))
    assert w.dtype == np.float64 and np.all(w <= 2.0) and w[2] == pytest.approx(1.0)
    assert np.all(np.diff(w) > 0)  # the order of the ratios kept
    jw = np.exp(np.asarray(rare.defensive(jnp.asarray(log_r, jnp.float32), jnp.float32(0.5))))
    np.testing.assert_allclose(jw, w, rtol=1e-5)


def test_a_mixture_component_weighs_from_its_statistics_as_the_program_does(smoke_run):
    """``--family mixture``: each one-role component's ``log p/q`` from the step statistics
    equals the tilted program's own ``log_w`` of the chunk it draws, for the conditional tilts
    and the constant-rate ones; under a conditional tilt every lane change with an event of
    the role weighs ``1 - (1 - p)^H`` to it whenever the event fell, one without
    ``(1 - (1 - p)^H) / (1 - (1 - p)^(H - trials))``; horizons of 0 and rates equal to the
    traffic's weigh every lane change 1, and no weight exceeds ``1 / alpha``."""
    from jaxlc.evaluation import mixture, proposal, validation
    from jaxlc.evaluation.cases import columns
    from jaxlc.evaluation.heldout import in_traffic
    from jaxlc.sim.env import EnvParams
    from jaxlc.study.rundir import RunDir

    cfg = in_traffic(RunDir(smoke_run[0]).load_config(), TRAFFIC)
    base = EnvParams.from_config(cfg.env)
    run = validation.program(cfg, config.EvalConfig().max_steps, True)  # the fixture's
    keys = streams.stream(0, streams.VALIDATE, range(CHUNK))
    pol = validation.policies(cfg, None, 1)
    start = mixture.start(base, 0.2, "entry", 60)
    p = start.p_fire
    col = {n: i for i, n in enumerate(proposal.STATS)}
    rates = dataclasses.replace(start, horizons=(), rates=(0.02, 0.01, 0.03, 0.004))
    for mix in (dataclasses.replace(start, horizons=(60.0, 40.0, 60.0, 200.0)), rates):
        for k, role in enumerate(proposal.ROLES):
            out = columns(jax.device_get(run(mix.component(base, k), pol, keys)[0]))
            st = out["tilt"][0].astype(np.float64)
            log_r = mix.log_ratios(st)
            assert st[:, col[f"brake_trials_{role}"]].sum() > 0  # the role's trials were drawn
            np.testing.assert_allclose(log_r[:, k], out["log_w"][0], rtol=1e-4, atol=1e-3)
            assert np.all(mix.log_weight(st) <= -math.log(0.2) + 1e-12)
            if not mix.horizons or role == "ahead":  # several trials a step: not one per event
                continue
            h = mix.horizons[k]
            events, trials = st[:, col[f"brake_events_{role}"]], st[:, col[f"brake_trials_{role}"]]
            first = st[:, col[f"brake_first_{role}"]]
            assert events.any() and np.all(first[events > 0] <= h)  # the event within H
            reach = -math.expm1(h * math.log1p(-p))
            none = -np.expm1(np.maximum(h - trials, 0) * math.log1p(-p)) / reach
            with np.errstate(divide="ignore"):  # past the horizon with no event: +inf
                expect = np.where(events > 0, math.log(reach), -np.log(none))
            np.testing.assert_allclose(log_r[:, k], expect, rtol=1e-3, atol=1e-3)
    out = columns(jax.device_get(run(mix.component(base, -1), pol, keys)[0]))
    flat = dataclasses.replace(rates, rates=(p,) * len(proposal.ROLES))
    assert np.all(np.abs(flat.log_weight(out["tilt"][0])) < 1e-12)
    zero = dataclasses.replace(start, horizons=(0.0,) * len(proposal.ROLES))
    out = columns(jax.device_get(run(zero.component(base, -1), pol, keys)[0]))
    assert np.all(np.abs(zero.log_weight(out["tilt"][0])) < 1e-12)


def test_the_conditional_hazard_puts_one_event_within_the_horizon():
    """``proposal.first_event_hazard`` over one trial a step: the first event's time has the
    traffic's distribution conditioned on falling within the horizon (so every path with one
    weighs the same), and no path goes past the horizon without one."""
    from jaxlc.evaluation import proposal

    p, h = 0.003, 50
    c = np.arange(h)
    q = np.asarray(
        proposal.first_event_hazard(
            jnp.float32(p),
            jnp.full(4, h, jnp.float32),
            jnp.asarray(c[:, None] * np.ones(4), jnp.float32),
            jnp.zeros((h, 4)),
        )
    )[:, 0].astype(np.float64)
    survive = np.concatenate([[1.0], np.cumprod(1 - q)])  # no event in the first c trials
    first = survive[:-1] * q  # (h,) the first event at trial c
    reach = 1 - (1 - p) ** h
    np.testing.assert_allclose(first, p * (1 - p) ** c / reach, rtol=1e-4)
    assert survive[-1] == pytest.approx(0.0, abs=1e-6) and q[-1] == pytest.approx(1.0)
    after = proposal.first_event_hazard(
        jnp.float32(p), jnp.full(4, h), jnp.full(4, 3.0), jnp.ones(4)
    )
    assert np.all(np.asarray(after) == np.float32(p))  # once the role braked: the traffic's


def test_fitted_shares_follow_the_failures_and_keep_every_role():
    """``mixture.fitted_shares``: a role the failures brake in more gets more, a role with a
    longer horizon more, and a role no failure braked in keeps a share."""
    from jaxlc.evaluation import mixture, proposal

    col = {n: i for i, n in enumerate(proposal.STATS)}
    st = np.zeros((10, len(proposal.STATS)))
    st[:8, col["brake_events_lead"]] = 1
    st[8:, col["brake_events_ahead"]] = 1
    shares = mixture.fitted_shares(np.ones(10), st, np.array([200.0] * 4), 1e-4)
    assert sum(shares) == pytest.approx(1.0)
    assert shares[0] > shares[3] > shares[1] > 0.05 and shares[1] == pytest.approx(shares[2])
    longer = mixture.fitted_shares(np.ones(10), st, np.array([200.0, 200, 200, 2000]), 1e-4)
    assert longer[3] > shares[3]


def test_the_mixtures_chunks_keep_its_shares():
    from jaxlc.evaluation import mixture

    mix = mixture.Mixture(1e-4, (0.01,) * 4, (0.4, 0.1, 0.3, 0.2), 0.2, "entry")
    comps: list[int] = []
    for _ in range(60):
        comps.append(mix.next_component(comps))
    for n in range(1, 61):
        drawn = mix.drawn(comps[:n])
        target = [mix.alpha, *(0.8 * s for s in mix.shares)]
        got = [drawn.alpha, *((1 - drawn.alpha) * s for s in drawn.shares)]
        assert all(abs(g * n - t * n) < 1 for g, t in zip(got, target, strict=True))
    at_50 = mix.drawn(comps[:50])  # 10 nominal chunks, 16, 4, 12 and 8 of the components
    assert at_50.alpha == 0.2 and at_50.shares == pytest.approx(mix.shares)


@pytest.fixture(scope="module")
def validated_mixture(validated, tmp_path_factory):
    """The smoke run validated by IS with the mixture of one-role tilts from the entry (the
    ``validated`` fixture's program, loaded)."""
    from jaxlc import validate

    run_dir, _ = validated
    out = tmp_path_factory.mktemp("validate_mixture")
    args = ["--model", "scripted", "--method", "is", "--family", "mixture", "--kind", "failure"]
    args += ["--tilt-from", "entry", "--chunk", str(CHUNK), "--lane-changes", "400"]
    args += ["--defensive", str(SHARE), "--out", str(out), "--traffic", *TRAFFIC]
    assert validate.main([str(run_dir), *args]) == 0
    return run_dir, out


def test_the_mixture_estimate_is_written_and_its_cases_replay(validated_mixture):
    import json

    from jaxlc.evaluation.validation_io import replay_case

    run_dir, out = validated_mixture
    (model,) = json.loads((out / "validate.json").read_text())["models"]
    mix = model["proposal"]
    assert mix["family"] == "mixture" and model["ce"] and model["lane_changes"] >= 400
    assert "a mixture of one-role braking tilts" in (out / "validate.md").read_text()
    assert sum(mix["shares"]) == pytest.approx(1.0) and mix["alpha"] == model["defensive"] > 0
    e = model["estimates"]["failure"]
    assert e["failures"] > 0 and e["lo"] <= e["estimate"] <= e["hi"]
    cases = json.loads((out / "cases.json").read_text())
    # each case records the component that drew it: one role's braking tilted, none for the
    # traffic's own draws
    for c in cases:
        tilted = np.asarray(c["proposal"]["conditional"]) > 0.5
        assert tilted.sum() == (0 if c["drawn_nominal"] else 1)
        assert np.all(np.asarray(c["proposal"]["brake"]) == np.float32(mix["p_fire"]))
        assert c["proposal"]["drawn_nominal"] == float(c["drawn_nominal"])
    assert any(not c["drawn_nominal"] for c in cases)
    path, same = replay_case(run_dir, 0, out)
    assert same and path.stat().st_size > 0


def test_bad_run_directory_is_one_line(tmp_path, capsys):
    from jaxlc import validate

    assert validate.main([str(tmp_path), "--method", "mc"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "not a run directory" in err and "\n" not in err


def test_a_mixture_without_braking_events_is_refused_in_one_line(smoke_run, capsys):
    from jaxlc import validate

    args = [str(smoke_run[0]), "--model", "scripted", "--family", "mixture"]
    assert validate.main(args) == 2  # the smoke run's traffic: the paper's, no braking events
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "env.braking=true" in err and "\n" not in err


def test_the_mixtures_pilots_set_each_horizon_to_the_most_trials_a_lane_change_held(
    monkeypatch,
):
    """``mixture.fit_mixture`` on a fake pilot program: after each round every horizon is the
    most braking trials of its role a performed pilot lane change held (not a case that never
    became one), each round and component draws keys of its own, and the shares favour the
    role the failures braked in."""
    from types import SimpleNamespace

    from jaxlc.evaluation import mixture, validation
    from jaxlc.evaluation.heldout import in_traffic
    from jaxlc.evaluation.proposal import ROLES, STATS
    from jaxlc.sim.env import EnvParams

    p = EnvParams.from_config(in_traffic(config.load(), ["env.braking=true"]).env)
    n, seen, col = 20, [], {name: i for i, name in enumerate(STATS)}

    def run(prop, pol, keys):
        seen.append(np.asarray(keys))
        r = len(seen)
        tilt = np.zeros((1, n, len(STATS)), np.float32)
        for k, role in enumerate(ROLES):  # trials grow with the case and the call
            tilt[0, :, col[f"brake_trials_{role}"]] = np.arange(n) + 10 * k + r
        tilt[0, :3, col["brake_events_lead"]] = 1  # the failures brake in the lead's role
        out = SimpleNamespace(
            names=(),
            performed=(np.arange(n) < n - 1)[None],  # the last case: no lane change
            log_w=np.zeros((1, n), np.float32),
            tilt=tilt,
            steps=np.arange(n)[None],
            reason=np.where(np.arange(n) < 3, 1, 0)[None],
        )
        return (out,)

    def kinds(out, dt):  # failure kind 0: the cases the fake run marked
        return np.stack([out["reason"][0] == 1] * len(validation.KINDS), axis=1)

    monkeypatch.setattr(validation, "kinds", kinds)
    start = mixture.start(p, 0.05, "entry", 100)
    mix, history = mixture.fit_mixture(run, None, p, start, n, kind="failure", log=lambda m: 0)
    calls = len(seen)
    assert calls == mixture.PILOT_ROUNDS * len(ROLES) and len({a.tobytes() for a in seen}) == calls
    # the most trials: the last performed case (n - 2) of the last call
    assert list(mix.horizons) == [n - 2 + 10 * k + calls for k in range(len(ROLES))]
    assert history[0]["mixture"]["horizons"][0] == n - 2 + len(ROLES)
    assert sum(mix.shares) == pytest.approx(1.0) and mix.shares[0] == max(mix.shares)
    assert history[-1]["pooled_failures"] == 3 * calls


@pytest.mark.slow
def test_benchmark_scripts_tiny(tmp_path, monkeypatch):
    """benchmarks/validate_throughput.py end to end, tiny (its ``main`` in this process: its
    imports and compiled programs shared with the suite)."""
    import sys

    from benchmarks import validate_throughput

    def run(script, *args: str) -> None:
        monkeypatch.setattr(sys, "argv", [script.__name__, *args, "--out", str(tmp_path)])
        script.main()

    # one traffic of the script's loop (the braking one: the paper's path is the simpler)
    args = ["--chunk", "8", "--repeats", "1", "--steps", "10", "--traffic", "braking"]
    run(validate_throughput, *args)
    rows = (tmp_path / "throughput.csv").read_text().splitlines()
    assert len(rows) == 2 and "share_of_sim" in rows[0] and rows[1].startswith("braking")


def test_ratio_estimate_with_unit_weights_is_the_plain_rate():
    rng = np.random.default_rng(0)
    perf = rng.random(10_000) < 0.7
    failed = perf & (rng.random(10_000) < 0.01)
    r = rare.is_ratio_estimate(np.zeros(10_000), perf, failed)
    assert r["estimate"] == pytest.approx(failed.sum() / perf.sum())
    assert r["lane_changes"] == perf.sum() and r["lo"] < r["estimate"] < r["hi"]


@pytest.mark.parametrize("first", [6, 2])
def test_the_ce_holds_its_proposal_for_a_round_that_as_many_failures_again_complete(
    first, monkeypatch
):
    """A pilot round with failures short of ``rare.MIN_ELITE`` (10): with 6, another round
    under the same proposal (new keys) pools 11 and the fit is to those failures; with 2,
    as many again would not do, and the round's closest by ``score`` are the elite."""
    from types import SimpleNamespace

    from jaxlc.evaluation import validation
    from jaxlc.evaluation.proposal import STATS
    from jaxlc.sim.env import EnvParams

    p = EnvParams.from_config(config.load().env)
    n, seen, said = 40, [], []  # 40: 2 failures are under the tenth that would make them elite
    fails = iter([first, 5, 5])

    def run(prop, pol, keys):
        seen.append(np.asarray(keys))
        k = next(fails)
        out = SimpleNamespace(
            names=(),
            performed=np.ones((1, n), bool),
            log_w=np.zeros((1, n), np.float32),
            tilt=np.ones((1, n, len(STATS)), np.float32),
            steps=np.arange(n)[None],
            reason=np.where(np.arange(n) < k, 1, 0)[None],
        )
        return (out,)

    def kinds(out, dt):  # failure kind 0: the cases the fake run marked
        return np.stack([out["reason"][0] == 1] * len(validation.KINDS), axis=1)

    monkeypatch.setattr(validation, "kinds", kinds)
    start = validation.start_proposal(p)
    _, history = validation.fit_proposal(
        run, None, p, start, n, kind="failure", rounds=3, log=said.append
    )
    assert not np.array_equal(seen[0], seen[1])  # each round on keys of its own
    moved = [h["proposal"] != start.to_dict() for h in history]
    if first == 6:
        assert history[0]["level"] is None and not moved[0] and "held" in said[0]
        assert history[1]["pooled_failures"] == 11 and history[1]["level"] == math.inf
        assert moved[1]
    else:
        assert math.isfinite(history[0]["level"]) and moved[0]


def test_the_reports_section_lists_each_failing_kind_of_a_committed_validation(tmp_path):
    """``validation_io.report_section`` on the crude-MC run the README's claim (d) cites (a
    committed ``validate.json``): nothing without one; with it, a row for the validated kind
    and for every kind that failed, the other kinds left out."""
    import json
    import shutil

    from jaxlc.evaluation import validation_io

    assert validation_io.report_section(tmp_path) == []
    from .conftest import ROOT

    src = ROOT / "benchmarks" / "validate_cpu_2026-11-27" / "mc_3M_m3" / "validate.json"
    (tmp_path / "validate").mkdir()
    shutil.copy(src, tmp_path / "validate" / "validate.json")
    doc = json.loads(src.read_text())
    lines = validation_io.report_section(tmp_path)
    assert lines[0].startswith("## How rarely it fails") and lines[-1] == ""
    rows = [line.split(" | ")[1] for line in lines if line.startswith("| ④")]
    (model,) = doc["models"]
    shown = [k for k, e in model["estimates"].items() if e["failures"] or k == doc["kind"]]
    assert rows == shown and doc["kind"] in rows and len(rows) < len(model["estimates"])


@pytest.mark.slow
def test_ams_writes_its_estimate_and_curve(smoke_run, tmp_path):
    """``--method ams`` end to end on the smoke run (scripted controller, few particles):
    the estimate inside its interval, the curve beside crude MC's, the figure."""
    import csv
    import json

    from jaxlc import validate

    run_dir, _ = smoke_run
    args = ["--model", "scripted", "--method", "ams", "--kind", "collision", "--margin", "2"]
    args += ["--particles", "12", "--kill", "0.25", "--repeats", "2", "--max-rounds", "4"]
    assert validate.main([str(run_dir), *args, "--out", str(tmp_path)]) == 0
    (doc,) = json.loads((tmp_path / "ams.json").read_text())
    assert len(doc["repeats"]) == 2 and doc["lo"] <= doc["estimate"] <= doc["hi"]
    assert doc["rl_steps"] > 0 and doc["cases_started"] >= 2 * 12
    rows = list(csv.DictReader((tmp_path / "ams_curve.csv").open()))
    probs = [float(r["ams"]) for r in rows]
    assert probs == sorted(probs) and all(0 <= p <= 1 for p in probs)  # a distribution
    assert (tmp_path / "ams_curve.png").stat().st_size > 0
