"""StoredRows (the refresh's next observations, read chunk by chunk) and the memory of a refresh on images."""

import os
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3.common.envs import FakeImageEnv

from sb3_offon import DataEfficientCNN, OffOnDQN, OffOnQRDQN
from sb3_offon.common.stored_rows import StoredRows


def identity(observations):
    return observations


def test_rows_are_the_stored_ones_by_slices():
    source = np.arange(5 * 3 * 2, dtype=np.uint8).reshape(5, 3, 2)  # (buffer_size, n_envs, features)
    slots, envs = np.array([4, 0, 2, 2, 1]), np.array([1, 2, 0, 2, 1])
    rows = StoredRows(source, slots, envs, identity)
    assert len(rows) == 5
    np.testing.assert_array_equal(rows[0:3], source[slots[:3], envs[:3]])
    np.testing.assert_array_equal(rows[3:5], source[slots[3:], envs[3:]])
    np.testing.assert_array_equal(np.asarray(rows), source[slots, envs])
    np.testing.assert_array_equal(rows.array(), source[slots, envs])


def test_a_read_reuses_the_array_of_the_one_before_and_array_is_a_copy():
    source = np.arange(8 * 1 * 3, dtype=np.float32).reshape(8, 1, 3)
    rows = StoredRows(source, np.arange(8), np.zeros(8, dtype=np.int64), identity)
    first = rows[0:4]
    second = rows[4:8]
    assert np.shares_memory(first, second), "one array for every chunk: the refresh holds one chunk at a time"
    np.testing.assert_array_equal(second, source[4:8, 0])
    whole = rows.array()
    assert not np.shares_memory(whole, source) and not np.shares_memory(whole, second)


def test_dict_observations_and_normalisation():
    source = {"a": np.arange(6, dtype=np.float32).reshape(3, 2, 1), "b": np.ones((3, 2, 2), dtype=np.float32)}
    rows = StoredRows(source, np.array([2, 0]), np.array([1, 0]), lambda obs: {key: 10 * value for key, value in obs.items()})
    chunk = rows[0:2]
    np.testing.assert_array_equal(chunk["a"].ravel(), [50.0, 0.0])
    np.testing.assert_array_equal(chunk["b"], np.full((2, 2), 10.0))
    with pytest.raises(TypeError, match="Dict observations"):
        np.asarray(rows)


def test_a_source_that_is_not_contiguous_is_indexed_as_it_is():
    source = np.arange(4 * 2 * 6, dtype=np.int64).reshape(4, 2, 6)[:, :, ::2]
    rows = StoredRows(source, np.array([3, 1]), np.array([0, 1]), identity)
    np.testing.assert_array_equal(rows[0:2], source[[3, 1], [0, 1]])


def test_read_by_a_slice_only():
    rows = StoredRows(np.zeros((2, 1, 1)), np.array([0]), np.array([0]), identity)
    with pytest.raises(TypeError, match="slices"):
        rows[0]


def filled_on_frames(algo: type, n_channels: int, n_steps: int, buffer_size: int, policy_kwargs: dict):
    """``algo`` on 84 x 84 frames of ``n_channels``, its buffer (without copies of the next frames) filled with
    ``n_steps`` transitions and nothing trained yet."""
    env = FakeImageEnv(screen_height=84, screen_width=84, n_channels=n_channels, discrete=True)
    model = algo(
        "CnnPolicy",
        env,
        buffer_size=buffer_size,
        learning_starts=10 * buffer_size,
        optimize_memory_usage=True,
        replay_buffer_kwargs=dict(handle_timeout_termination=False),
        policy_kwargs=policy_kwargs,
        seed=0,
    )
    model.learn(n_steps)
    return model


@pytest.mark.parametrize("algo", [OffOnDQN, OffOnQRDQN])
def test_a_refresh_on_images_holds_one_chunk_of_next_observations_not_all_of_them(algo):
    # 4,000 targets of 84 x 84 frames: 28 MB of next observations if gathered at once (as before StoredRows), about
    # 2 MB a chunk (LAMBDA_FORWARD_BYTES of float32 frames: 297 rows of 7 KB) now
    policy_kwargs = dict(net_arch=[16]) if algo is OffOnDQN else dict(net_arch=[16], n_quantiles=5)
    model = filled_on_frames(algo, n_channels=1, n_steps=4_500, buffer_size=5_000, policy_kwargs=policy_kwargs)
    n_targets = 4_000
    gathered_at_once = n_targets * 84 * 84
    tracemalloc.start()
    try:
        cache = model._compute_lambda_cache(n_targets, key=0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(cache.returns) >= n_targets
    assert peak < 0.3 * gathered_at_once, f"peak {peak / 2**20:.1f} MiB of NumPy memory in the refresh"


def resident_gb() -> float:
    """This process's resident memory (Linux)."""
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e9


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/statm").is_file(), reason="reads the resident memory from /proc (Linux)")
def test_a_refresh_on_frames_leaves_the_process_no_larger():
    # 6,000 targets of 4 x 84 x 84 frames through DER's network: a list of each chunk's outputs, concatenated at the
    # end, left the process 0.38 GB larger when measured (the C allocator's heap grown chunk after chunk); outputs
    # written into tensors made once, a few tens of MB
    policy_kwargs = dict(features_extractor_class=DataEfficientCNN, net_arch=[])
    model = filled_on_frames(OffOnDQN, n_channels=4, n_steps=6_000, buffer_size=10_000, policy_kwargs=policy_kwargs)
    before = resident_gb()
    cache = model._compute_lambda_cache(64_000, key=0)
    assert len(cache.returns) == 6_000
    assert resident_gb() - before < 0.15
