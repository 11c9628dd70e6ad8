"""The sum tree of prioritised replay: hand-computed sums and searches, sampling frequencies, updates, errors, pickling."""

import copy
import pickle

import numpy as np
import pytest

from sb3_offon.common.sum_tree import SumTree

# Capacity 5 pads to 8 leaves; the prefix sums of [1, 0, 3, 2, 4] are 0, 1, 1, 4, 6, 10
FIVE_LEAVES = np.array([1.0, 0.0, 3.0, 2.0, 4.0])
# Eight leaves with unequal priorities, one of them 0: probabilities 0.05, 0.1, 0, 0.2, 0.15, 0.25, 0.2, 0.05
EIGHT_LEAVES = np.array([1.0, 2.0, 0.0, 4.0, 3.0, 5.0, 4.0, 1.0])
N_DRAWS = 200_000


def make_tree(priorities: np.ndarray) -> SumTree:
    tree = SumTree(len(priorities))
    tree.update(np.arange(len(priorities)), priorities)
    return tree


def assert_frequencies(indices: np.ndarray, priorities: np.ndarray) -> None:
    """Each leaf's frequency within 5 standard errors of independent draws of p_i / sum p; zero leaves never drawn."""
    n = indices.size
    probabilities = priorities / priorities.sum()
    counts = np.bincount(indices, minlength=len(priorities))
    assert counts.sum() == n
    assert np.all(counts[priorities == 0] == 0)
    standard_errors = np.sqrt(probabilities * (1 - probabilities) / n)
    np.testing.assert_array_less(np.abs(counts / n - probabilities), 5 * standard_errors + 1e-12)


def test_five_leaves_sums_and_find() -> None:
    tree = make_tree(FIVE_LEAVES)
    assert len(tree) == 5
    assert tree.total == 10.0
    assert tree.min == 1.0
    np.testing.assert_array_equal(tree.values(np.arange(5)), FIVE_LEAVES)
    np.testing.assert_array_equal(tree.probabilities(np.array([0, 1, 4])), [0.1, 0.0, 0.4])

    prefix_sums = np.array([0.0, 0.999999, np.nextafter(1.0, 0.0), 1.0, 2.5, 3.999999, 4.0, 5.5, 6.0, 9.999999])
    expected = np.array([0, 0, 0, 2, 2, 2, 3, 3, 4, 4])  # 1.0 skips the empty leaf 1 for leaf 2
    np.testing.assert_array_equal(tree.find(prefix_sums), expected)
    # The right edge: the last positive leaf (4), never an empty padded one (5, 6, 7)
    edges = np.array([10.0, 10.0 - 1e-12, np.nextafter(10.0, 0.0)])
    np.testing.assert_array_equal(tree.find(edges), [4, 4, 4])
    # Any shape in, the same shape out
    np.testing.assert_array_equal(tree.find(np.array([[0.5, 1.5], [4.5, 10.0]])), [[0, 2], [3, 4]])


def test_find_never_returns_an_empty_leaf_at_the_edges() -> None:
    # The last positive leaf is followed by empty leaves within the same subtrees: total lands on it, not past it
    tree = make_tree(np.array([0.0, 3.0, 0.0, 0.0, 0.0, 0.0]))
    np.testing.assert_array_equal(tree.find(np.array([0.0, 1.5, 3.0 - 1e-12, 3.0])), [1, 1, 1, 1])
    # Sums that do not add up exactly in floating point (0.1 + 0.2 + 0.3 rounds): every value in [0, total] is positive
    tree = make_tree(np.array([0.1, 0.0, 0.2, 0.0, 0.3, 0.0, 0.0]))
    values = np.concatenate([np.linspace(0.0, tree.total, 10_001), [np.nextafter(tree.total, 0.0), 0.1, 0.3, 0.6]])
    found = tree.find(values)
    assert set(np.unique(found)) == {0, 2, 4}
    assert found[-4] == 4 and found[-3] == 2 and found[-1] == 4

    # Random trees with empty leaves: just below total, u less the left sums rounds at or beyond the right sums in about
    # 1 tree in 100 (a descent without the guard then ends on an empty or padded leaf)
    rng = np.random.default_rng(0)
    for _ in range(3_000):
        priorities = np.where(rng.random(6) < 0.4, 0.0, rng.random(6))
        if priorities.sum() == 0:
            continue
        tree = make_tree(priorities)
        values = np.array([np.nextafter(tree.total, 0.0), tree.total, *rng.uniform(0.0, tree.total, size=8)])
        assert np.all(priorities[tree.find(values)] > 0)


def test_find_is_a_search_of_the_prefix_sums() -> None:
    # Integer priorities: the prefix sums are exact, and the leaf of u is the number of prefix sums at or below it
    rng = np.random.default_rng(2)
    for capacity in (2, 3, 13, 64, 100):
        priorities = rng.integers(0, 4, size=capacity).astype(np.float64)
        priorities[-1] = 1.0
        tree = make_tree(priorities)
        cumulative = np.cumsum(priorities)
        values = np.concatenate([rng.uniform(0.0, tree.total, size=1_000), cumulative[:-1], np.arange(tree.total)])
        np.testing.assert_array_equal(tree.find(values), np.searchsorted(cumulative, values, side="right"))


def test_capacity_one() -> None:
    tree = SumTree(1)
    assert len(tree) == 1
    assert tree.total == 0.0 and tree.min == np.inf
    tree.update(np.array([0]), np.array([2.5]))
    assert tree.total == 2.5 and tree.min == 2.5
    np.testing.assert_array_equal(tree.find(np.array([0.0, 1.0, 2.5])), [0, 0, 0])
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(tree.sample(4, rng), [0, 0, 0, 0])
    np.testing.assert_array_equal(tree.sample_proportional(3, rng), [0, 0, 0])
    np.testing.assert_array_equal(tree.probabilities(np.array([0])), [1.0])


def test_large_capacity() -> None:
    capacity = 2**17 + 3  # pads to 2**18 leaves
    tree = SumTree(capacity)
    priorities = (np.arange(capacity) % 7 + 1).astype(np.float64)  # integers: the sum is exact
    tree.update(np.arange(capacity), priorities)
    assert len(tree) == capacity
    assert tree.total == float(priorities.sum()) == 4.0 * capacity  # 131075 = 7 * 18725 cycles of 1..7, mean 4
    assert tree.min == 1.0
    assert tree.find(np.array([tree.total]))[0] == capacity - 1
    indices = tree.sample(1024, np.random.default_rng(0))
    assert indices.shape == (1024,) and indices.dtype == np.int64
    assert np.all((indices >= 0) & (indices < capacity))
    assert np.all(np.diff(indices) >= 0)  # draw k comes from segment k


def test_sample_frequencies() -> None:
    tree = make_tree(EIGHT_LEAVES)
    np.testing.assert_allclose(tree.probabilities(np.arange(8)), [0.05, 0.1, 0, 0.2, 0.15, 0.25, 0.2, 0.05])
    rng = np.random.default_rng(12345)
    # Batches of 32 as a replay buffer draws them; one batch of 200,000 strata would hit the expected counts nearly exactly
    stratified = np.concatenate([tree.sample(32, rng) for _ in range(N_DRAWS // 32 + 1)])[:N_DRAWS]
    assert_frequencies(stratified, EIGHT_LEAVES)
    independent = tree.sample_proportional(N_DRAWS, rng)
    assert_frequencies(independent, EIGHT_LEAVES)


def test_stratified_sampling_draws_one_value_per_segment() -> None:
    # Equal priorities, as many segments as leaves: each segment is one leaf, each leaf is drawn once, in order
    tree = make_tree(np.full(8, 0.5))
    rng = np.random.default_rng(1)
    for _ in range(20):
        np.testing.assert_array_equal(tree.sample(8, rng), np.arange(8))
        np.testing.assert_array_equal(tree.sample(16, rng), np.repeat(np.arange(8), 2))

    # Unequal priorities: draw k's leaf interval [sum(p[:i]), sum(p[:i + 1])) meets segment [k, k + 1) * total / batch
    tree = make_tree(EIGHT_LEAVES)
    starts = np.concatenate([[0.0], np.cumsum(EIGHT_LEAVES)])
    for batch_size in (1, 5, 20, 64):
        segment = tree.total / batch_size
        for _ in range(50):
            indices = tree.sample(batch_size, rng)
            k = np.arange(batch_size)
            assert np.all(EIGHT_LEAVES[indices] > 0)
            assert np.all(starts[indices] < (k + 1) * segment)
            assert np.all(starts[indices + 1] > k * segment)
    # With 20 segments of 1 and leaf 3 = [3, 7): segments 3 to 6 all draw leaf 3
    indices = tree.sample(20, rng)
    np.testing.assert_array_equal(indices, [0, 1, 1, 3, 3, 3, 3, 4, 4, 4, 5, 5, 5, 5, 5, 6, 6, 6, 6, 7])


def test_repeated_indices_last_wins() -> None:
    tree = make_tree(FIVE_LEAVES)
    tree.update(np.array([2, 2, 2]), np.array([5.0, 6.0, 7.0]))
    assert tree.values(np.array([2]))[0] == 7.0
    tree.update(np.array([0, 3, 0, 4, 0]), np.array([9.0, 1.0, 8.0, 0.5, 0.25]))
    np.testing.assert_array_equal(tree.values(np.arange(5)), [0.25, 0.0, 7.0, 1.0, 0.5])
    assert tree.total == 8.75
    assert tree.min == 0.25
    # A scalar priority for all indices; an empty update changes nothing
    tree.update(np.array([1, 3]), np.array(2.0))
    np.testing.assert_array_equal(tree.values(np.arange(5)), [0.25, 2.0, 7.0, 2.0, 0.5])
    tree.update(np.array([], dtype=np.int64), np.array([]))
    assert tree.total == 11.75


def test_update_to_zero_empties_a_leaf() -> None:
    tree = make_tree(FIVE_LEAVES)
    tree.update(np.array([0]), np.array([0.0]))
    assert tree.total == 9.0
    assert tree.min == 2.0  # the min moves on to the smallest positive leaf, not to the new 0
    np.testing.assert_array_equal(tree.find(np.array([0.0, 2.999, 3.0, 9.0])), [2, 2, 3, 4])
    rng = np.random.default_rng(3)
    drawn = np.concatenate([tree.sample(64, rng), tree.sample_proportional(10_000, rng)])
    assert set(np.unique(drawn)) == {2, 3, 4}
    # Emptied one by one down to nothing: the min is +inf and sampling refuses
    tree.update(np.array([3]), np.array([0.0]))
    assert tree.min == 3.0 and tree.total == 7.0  # leaves [0, 0, 3, 0, 4]
    tree.update(np.array([2]), np.array([0.0]))
    assert tree.min == 4.0 and tree.total == 4.0
    np.testing.assert_array_equal(tree.find(np.array([0.0, 4.0])), [4, 4])
    tree.update(np.array([4]), np.array([0.0]))
    assert tree.min == np.inf and tree.total == 0.0
    with pytest.raises(ValueError, match="all 0"):
        tree.sample(1, rng)


def test_many_random_updates_against_numpy() -> None:
    capacity = 100  # pads to 128
    rng = np.random.default_rng(7)
    tree = SumTree(capacity)
    reference = np.zeros(capacity)
    for step in range(2_000):  # 10,000 single updates in batches of 5, repeats included
        indices = rng.integers(0, capacity, size=5)
        # Priorities over twelve orders of magnitude, a tenth of them 0
        priorities = np.where(rng.random(5) < 0.1, 0.0, np.exp(rng.uniform(-14.0, 14.0, size=5)))
        tree.update(indices, priorities)
        for index, priority in zip(indices, priorities, strict=True):
            reference[index] = priority
        if step % 100 == 0:
            np.testing.assert_array_equal(tree.values(np.arange(capacity)), reference)
    np.testing.assert_array_equal(tree.values(np.arange(capacity)), reference)
    assert tree.total == pytest.approx(reference.sum(), rel=1e-9, abs=0)
    assert tree.min == reference[reference > 0].min()
    # No drift: a tree built at once from the same leaves has the same sums bit for bit
    fresh = make_tree(reference)
    assert tree.total == fresh.total
    assert tree.min == fresh.min
    values = np.linspace(0.0, tree.total, 1_001)
    np.testing.assert_array_equal(tree.find(values), fresh.find(values))


@pytest.mark.parametrize("bad, message", [(-1.0, "non-negative"), (np.nan, "finite"), (np.inf, "finite"), (-np.inf, "finite")])
def test_bad_priorities(bad: float, message: str) -> None:
    tree = make_tree(FIVE_LEAVES)
    with pytest.raises(ValueError, match=message):
        tree.update(np.array([0, 1]), np.array([2.0, bad]))
    np.testing.assert_array_equal(tree.values(np.arange(5)), FIVE_LEAVES)  # a refused update changes nothing


def test_bad_arguments() -> None:
    tree = make_tree(FIVE_LEAVES)
    rng = np.random.default_rng(0)
    for value in (-1e-9, 10.0 + 1e-9, np.nan, np.inf):
        with pytest.raises(ValueError, match=r"values in \[0, total"):
            tree.find(np.array([1.0, value]))
    with pytest.raises(ValueError, match="all 0"):
        SumTree(4).sample(2, rng)
    with pytest.raises(ValueError, match="all 0"):
        SumTree(4).sample_proportional(2, rng)
    with pytest.raises(ValueError, match="all 0"):
        SumTree(4).find(np.array([0.0]))
    with pytest.raises(ValueError, match="all 0"):
        SumTree(4).probabilities(np.array([0]))
    with pytest.raises(ValueError, match=r"indices must lie in \[0, 5\)"):
        tree.update(np.array([5]), np.array([1.0]))
    with pytest.raises(ValueError, match=r"indices must lie in \[0, 5\)"):
        tree.values(np.array([-1]))
    with pytest.raises(ValueError, match="must be integers"):
        tree.values(np.array([1.0]))
    with pytest.raises(ValueError, match="one priority per index"):
        tree.update(np.array([0, 1, 2]), np.array([1.0, 2.0]))
    with pytest.raises(ValueError, match="batch size must be a positive integer"):
        tree.sample(0, rng)
    for capacity in (0, -3, 2.0):
        with pytest.raises(ValueError, match="positive integer"):
            SumTree(capacity)  # type: ignore[arg-type]


def test_pickle_and_copy_round_trip() -> None:
    tree = make_tree(EIGHT_LEAVES)
    for clone in (pickle.loads(pickle.dumps(tree)), copy.deepcopy(tree)):
        assert isinstance(clone, SumTree)
        assert len(clone) == 8 and clone.total == tree.total and clone.min == tree.min
        np.testing.assert_array_equal(clone.sample(256, np.random.default_rng(5)), tree.sample(256, np.random.default_rng(5)))
        np.testing.assert_array_equal(
            clone.sample_proportional(256, np.random.default_rng(6)), tree.sample_proportional(256, np.random.default_rng(6))
        )
        clone.update(np.array([0]), np.array([100.0]))  # the clone owns its arrays
        assert tree.total == 20.0
    assert all(type(value) in (int, float, np.ndarray) for value in vars(tree).values())
