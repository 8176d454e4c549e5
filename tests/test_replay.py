"""Replay memory under vmap: ring semantics per model capacity, masked insertion, sampling."""

from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxlc.learn import replay

CAPS = (5, 7, 9)
CAP_MAX = 9
OBS_DIM = 2
N = 5  # rows offered per insertion: <= the smallest capacity, as add() requires


def _rows(ids: np.ndarray) -> tuple[jax.Array, ...]:
    """Transition fields derived from integer ids (> 0, so an unwritten zero slot shows)."""
    ids = jnp.asarray(ids, jnp.float32)  # (models, N)
    obs = jnp.stack([ids, -ids], -1)
    return obs, ids[..., None] * 0.5, ids * 2.0, obs + 100.0, (ids % 2 == 0).astype(jnp.float32)


@pytest.fixture(scope="module")
def fns():
    add = jax.jit(jax.vmap(replay.add))
    sample = jax.jit(jax.vmap(replay.sample, in_axes=(0, 0, None)), static_argnums=2)
    empty = jax.vmap(lambda c: replay.init(CAP_MAX, OBS_DIM, 1, c))(jnp.asarray(CAPS))
    return add, sample, empty


def _stored_ids(mem: replay.Replay, m: int) -> list[int]:
    """Ids of model m oldest first, read in ring order ending just before ptr."""
    size, ptr, cap = int(mem.size[m]), int(mem.ptr[m]), int(mem.capacity[m])
    slots = [(ptr - size + j) % cap for j in range(size)]
    return [int(mem.obs[m, s, 0]) for s in slots]


def test_keeps_the_capacity_most_recent_valid_rows(fns):
    add, _, mem = fns
    rng = np.random.default_rng(0)
    ref = [deque(maxlen=c) for c in CAPS]
    next_id = 1
    for _ in range(12):
        ids = np.arange(next_id, next_id + len(CAPS) * N).reshape(len(CAPS), N)
        next_id += ids.size
        valid = rng.random((len(CAPS), N)) < 0.6
        valid[0] = False if _ == 3 else valid[0]  # an insertion with no valid row at all
        mem = add(mem, *_rows(ids), jnp.asarray(valid))
        for m in range(len(CAPS)):
            ref[m].extend(ids[m][valid[m]].tolist())
            assert int(mem.size[m]) == len(ref[m])
            assert _stored_ids(mem, m) == list(ref[m])
    obs, action, reward, next_obs, term = _rows(np.asarray(mem.obs[..., 0]))
    written = np.asarray(mem.obs[..., 0]) > 0
    for got, want in [
        (mem.action, action),
        (mem.reward, reward),
        (mem.next_obs, next_obs),
        (mem.terminated, term),
    ]:
        np.testing.assert_array_equal(np.asarray(got)[written], np.asarray(want)[written])
    for m, cap in enumerate(CAPS):  # slots past a model's capacity are never touched
        assert not np.any(np.asarray(mem.obs[m, cap:]))


def test_sampling_returns_only_written_rows(fns):
    add, sample, mem = fns
    ids = np.arange(1, len(CAPS) * N + 1).reshape(len(CAPS), N)
    valid = np.zeros((len(CAPS), N), bool)
    valid[0, :1], valid[1, :3], valid[2, :4] = True, True, True  # partly filled memories
    mem = add(mem, *_rows(ids), jnp.asarray(valid))
    keys = jax.random.split(jax.random.key(1), len(CAPS))
    batch = sample(mem, keys, 512)
    for m in range(len(CAPS)):
        got = np.asarray(batch["obs"][m, :, 0]).astype(int)
        assert set(got) == set(ids[m][valid[m]].tolist())  # all written rows, nothing else
        np.testing.assert_array_equal(np.asarray(batch["reward"][m]), got * 2.0)
        np.testing.assert_array_equal(np.asarray(batch["next_obs"][m, :, 1]), 100.0 - got)
    assert batch["action"].shape == (len(CAPS), 512, 1)
    assert batch["terminated"].shape == (len(CAPS), 512)


def test_mirrored_sampling_reflects_about_half_the_rows_and_draws_the_same_slots(fns):
    """``ddpg.mirror``: each drawn transition is either as stored or reflected (obs and next
    obs times the signs, action negated, reward and end kept), from the same slots."""
    add, _, mem = fns
    ids = np.arange(1, len(CAPS) * N + 1).reshape(len(CAPS), N)
    mem = add(mem, *_rows(ids), jnp.ones((len(CAPS), N), bool))
    one = jax.tree.map(lambda x: x[2], mem)  # model 2
    signs = (-1.0, 1.0)  # OBS_DIM = 2: the first entry flips
    key = jax.random.key(3)
    plain = replay.sample(one, key, 256)
    mirrored = replay.sample(one, key, 256, signs)
    np.testing.assert_array_equal(np.asarray(mirrored["reward"]), np.asarray(plain["reward"]))
    np.testing.assert_array_equal(mirrored["terminated"], plain["terminated"])
    flipped = np.asarray(mirrored["action"][:, 0]) == -np.asarray(plain["action"][:, 0])
    assert 0.3 < flipped.mean() < 0.7  # reflected with probability 1/2
    want = np.where(flipped[:, None], np.asarray(signs), 1.0)
    for name in ("obs", "next_obs"):
        np.testing.assert_array_equal(np.asarray(mirrored[name]), np.asarray(plain[name]) * want)
    kept = np.asarray(mirrored["action"][~flipped, 0]) == np.asarray(plain["action"][~flipped, 0])
    assert kept.all()


@pytest.mark.slow
def test_paired_sampling_holds_each_drawn_transition_and_its_reflection(fns):
    """``ddpg.mirror_pairs``: a batch of 2n rows is n stored transitions, then the same n
    reflected in the same order (obs and next obs times the signs, each action entry times
    its sign, reward and end kept): the layout ``Actor.paired`` reads."""
    add, _, mem = fns
    ids = np.arange(1, len(CAPS) * N + 1).reshape(len(CAPS), N)
    mem = add(mem, *_rows(ids), jnp.ones((len(CAPS), N), bool))
    one = jax.tree.map(lambda x: x[1], mem)  # model 1
    signs = (-1.0, 1.0)
    batch = {
        k: np.asarray(v)
        for k, v in replay.sample(one, jax.random.key(5), 64, signs, None, True).items()
    }
    half = {k: v[:32] for k, v in batch.items()}
    assert set(half["obs"][:, 0].astype(int)) <= set(ids[1].tolist())  # written rows only
    assert len(set(half["obs"][:, 0].astype(int))) > 1  # several transitions drawn
    for name in ("obs", "next_obs"):
        np.testing.assert_array_equal(batch[name][32:], half[name] * np.asarray(signs))
    np.testing.assert_array_equal(batch["action"][32:], -half["action"])
    for name in ("reward", "terminated"):
        np.testing.assert_array_equal(batch[name][32:], half[name])
    # an even second action entry keeps its sign
    two = one.replace(action=jnp.concatenate([one.action, one.action + 1.0], axis=-1))
    b2 = replay.sample(two, jax.random.key(5), 64, signs, (-1.0, 1.0), True)
    np.testing.assert_array_equal(
        np.asarray(b2["action"][32:]), np.asarray(b2["action"][:32]) * [-1, 1]
    )
