"""The models axis laid over several devices gives the results of one device."""

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import jax, numpy as np
    from jaxlc import config, train
    cfg = config.load(config.CONFIG_DIR / "smoke.toml")
    grid = train.make_grid(cfg)  # 4 models: padded to 6 on 3 devices
    assert len(jax.devices()) == 4, jax.devices()
    results = {}
    for n in (1, 3, 4):
        init, run = train.make_grid_fns(cfg, grid, jax.devices()[:n])
        state, metrics = run(init(train.model_keys(cfg, grid)), 300)
        assert state.episodes.shape == (grid.size,) and metrics["finite"].shape[1] == grid.size
        assert int(state.learner.step.min()) > 0, "updates must have run"
        results[n] = state
    for n in (3, 4):
        for a, b in zip(jax.tree.leaves(results[1]), jax.tree.leaves(results[n]), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-5)
    print("devices ok")
""")


def test_grid_over_3_and_4_cpu_devices_matches_one_device():
    env = {
        **os.environ,
        "XLA_FLAGS": "--xla_force_host_platform_device_count=4",
        "JAX_PLATFORMS": "cpu",
    }
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=900
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "devices ok" in done.stdout
