"""Shared fixtures: one smoke sweep per test worker (compiling is the expensive part).

Compiled programs are also shared on disk: the suite sets JAX's persistent compilation cache to
a directory of its own, made empty at the start of the run and removed at its end, so a program
that one worker, one fixture or one ``python -m jaxlc.sweep`` subprocess compiled is loaded, not
compiled again, by the others (the same config traced the same way gives the same program).
A ``JAX_COMPILATION_CACHE_DIR`` already set is used as it is and left in place.

Programs are compiled for the suite (``SUITE_XLA_FLAGS``, each unless ``XLA_FLAGS`` names its
key): at LLVM's optimisation level 1 (XLA's default is 3) and with XLA's older CPU fusion
emitters (``--xla_cpu_use_fusion_emitters=false``; the default build uses the new ones): on a
CPU the old emitters compile a program in about 30% less CPU time than level 1 alone, where
the simulator's large batches run slower on them (so a user's build keeps the defaults).
``XLA_FLAGS="--xla_backend_optimization_level=3 --xla_cpu_use_fusion_emitters=true"`` runs the
suite on the build a user gets. Its arithmetic may differ from the default build's in the last
bits (a smoke sweep's checkpoints do; the 3,000-step golden rollout does not), so every
comparison here is within one build, and the pin of the default build's numbers
(``tests/test_rollout_golden.py``'s first test) also runs on XLA's defaults, in a subprocess.
Subprocesses inherit the flags.

The test files run heaviest first (``HEAVY_FIRST``): ``--dist loadfile`` hands files to the
workers in collection order, and a heavy file started last would run on after the rest.
"""

import os
import shutil
import tempfile
from pathlib import Path

CACHE_ENV = "JAX_COMPILATION_CACHE_DIR"
# Set before jax is imported (here and in every xdist worker and subprocess, which inherit it).
_OWN_CACHE = None if os.environ.get(CACHE_ENV) else tempfile.mkdtemp(prefix="jaxlc-tests-xla-")
if _OWN_CACHE is not None:
    os.environ[CACHE_ENV] = _OWN_CACHE
    # every program, not only those over 1 s to compile: the small ones add up across tests
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
# XLA's CPU build for the suite: each where ``XLA_FLAGS`` does not name its key already.
SUITE_XLA_FLAGS = ("--xla_backend_optimization_level=1", "--xla_cpu_use_fusion_emitters=false")
for _flag in SUITE_XLA_FLAGS:
    if _flag.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_flag}".strip()

import jax  # noqa: E402
import pytest  # noqa: E402

from jaxlc import config, sweep  # noqa: E402

jax.config.update("jax_compilation_cache_dir", os.environ[CACHE_ENV])  # if jax came in first
if _OWN_CACHE is not None:
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)

SMOKE = config.CONFIG_DIR / "smoke.toml"

# Only stops a hung subprocess; never a speed judgement: a run slower than this is broken.
HANG_GUARD_S = 3600
ROOT = Path(__file__).resolve().parent.parent  # where ``python -m benchmarks.NAME`` runs


def changed_env_keys(name: str, base: config.Config) -> set[str]:
    """The ``env`` keys where ``configs/NAME`` differs from ``base``, after checking that the
    file spells out every key of every table (a config read beside another is like for like
    only where it says so)."""
    import dataclasses
    import tomllib

    written = tomllib.loads((config.CONFIG_DIR / name).read_text())
    loaded = config.load(config.CONFIG_DIR / name)
    for table in dataclasses.fields(loaded):
        keys = {f.name for f in dataclasses.fields(getattr(loaded, table.name))}
        assert set(written[table.name]) == keys, table.name
    return {
        f.name
        for f in dataclasses.fields(loaded.env)
        if getattr(loaded.env, f.name) != getattr(base.env, f.name)
    }


def wait_for_line(proc, start: str) -> None:
    """Read ``proc``'s stderr until a line starts with ``start`` (``sweep.HOLD_LINE``: the
    run holds); fail with what it printed if it ends first."""
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if line.startswith(start):
            return
    pytest.fail(f"the process ended before '{start}': {''.join(seen)[-3000:]}")


@pytest.fixture(scope="session")
def smoke_cfg():
    return config.load(SMOKE)


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory, smoke_cfg):
    """``(run_dir, summary)`` of one uninterrupted smoke sweep."""
    out = tmp_path_factory.mktemp("smoke_run")
    return out, sweep.run_sweep(smoke_cfg, out, progress=False)


# Seconds of each file in a run on the 2-core VM, heaviest first; files not named run after.
HEAVY_FIRST = (
    "test_runs_evaluate.py",
    "test_devices.py",
    "test_validate.py",
    "test_runs_evaluate_joint.py",
    "test_benchmarks.py",
    "test_traffic.py",
    "test_env.py",
    "test_ecosystem.py",
    "test_evaluate.py",
    "test_assist.py",
    "test_train.py",
    "test_reward_terms.py",
    "test_faults.py",
    "test_gym.py",
    "test_ddpg.py",
    "test_merge.py",
    "test_gymnax.py",
    "test_ranges.py",
    "test_joint.py",
    "test_heldout.py",
    "test_export.py",
    "test_notebook.py",
    "test_params.py",
    "test_rollout_golden.py",
)


# The quick tier (``-m "not slow"``): a test is slow when it uses one of these fixtures (each
# compiles and runs a sweep, an evaluation or a long rollout), when its file is in SLOW_FILES,
# or when it carries ``@pytest.mark.slow`` itself.
SLOW_FIXTURES = {
    "smoke_run",  # conftest: one smoke sweep per worker
    "runs",  # test_merge, test_runs_evaluate*: sweeps and their evaluation
    "validated",  # test_validate: jaxlc.validate on the smoke run
    "exported",  # test_export: ONNX export of the smoke run
    "tracked",  # test_tracking: a tracked smoke sweep
    "long_run",  # test_traffic: 102,400 env-steps at the highest rates
    "rows",  # test_ecosystem: Rejax's learners trained
    "rollout",  # test_env, test_gymnax, test_reward_terms: long rollouts
    "rollouts",  # test_joint
    "run",  # test_evaluate, test_ranges: compiled evaluation programs
}
SLOW_FILES = {"test_devices.py", "test_notebook.py", "test_rollout_golden.py"}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Marks the slow tests (above); then the heaviest files first (``--no-loadscope-reorder``
    keeps this order), a file's own tests keeping theirs."""
    for item in items:
        if item.path.name in SLOW_FILES or SLOW_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: the cores this process may use (``taskset`` included), not the machine's."""
    return len(os.sched_getaffinity(0))


def pytest_unconfigure(config: pytest.Config) -> None:
    """The process that made the compilation cache (xdist's controller) removes it."""
    if _OWN_CACHE is not None:
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)
