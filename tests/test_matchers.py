"""The matcher registry (gtsweep.stages.match.MATCHERS): each matcher on descriptor sets whose nearest neighbours
are known, strict parameters, and the NA of a forced FLANN index on descriptors of the other kind."""
import numpy as np
import pytest

from gtsweep.core.errors import BadInput, NotApplicable, UnknownMethod
from gtsweep.stages.match import MATCHERS, applicability, match_descriptors


def float_sets(n_ref=400, dims=32, seed=0):
    """Reference descriptors far apart (uniform in [0, 1)^32: nearest distances ~1.5) and test descriptors = every
    second reference plus noise of 0.001: test i's nearest neighbour is reference 2i, by a ratio far below 0.7."""
    rng = np.random.default_rng(seed)
    reference = rng.random((n_ref, dims), dtype=np.float32)
    test = reference[::2] + rng.normal(0, 0.001, (n_ref // 2, dims)).astype(np.float32)
    return test, reference


def binary_sets(n_ref=400, seed=0):
    """Random 256-bit reference descriptors (pairwise distances ~128) and test = every second reference with one
    bit flipped: test i's nearest neighbour is reference 2i at distance 1."""
    rng = np.random.default_rng(seed)
    reference = rng.integers(0, 256, (n_ref, 32), dtype=np.uint8)
    test = reference[::2].copy()
    test[:, 5] ^= 0b100
    return test, reference


@pytest.mark.parametrize("name", ["bf_ratio", "mutual_nn", "flann"])
@pytest.mark.parametrize("norm, sets", [("l2", float_sets), ("hamming", binary_sets)])
def test_every_matcher_finds_the_known_nearest_neighbours(name, norm, sets):
    test, reference = sets()
    matcher = MATCHERS.get(name).build()
    matches = matcher.index(reference, norm).match(test)
    assert matches.dtype == np.int64 and matches.shape == (len(test), 2)
    assert matches[:, 0].tolist() == list(range(len(test)))  # test order
    assert (matches[:, 1] == 2 * matches[:, 0]).all()


def test_bf_ratio_is_todays_matcher_bit_for_bit():
    rng = np.random.default_rng(3)
    reference, test = rng.random((300, 16), dtype=np.float32), rng.random((200, 16), dtype=np.float32)
    for params in ({}, {"mutual": True}, {"ratio": 0.9}):
        built = MATCHERS.get("bf_ratio").build(params)
        expected = match_descriptors(test, reference, "l2", params.get("ratio", 0.7), params.get("mutual", False))
        assert np.array_equal(built.index(reference, "l2").match(test), expected)
    assert len(expected) > 0


def test_mutual_nn_has_no_ratio_test_by_hand():
    reference = np.array([[0.0], [10.0]], np.float32)
    test = np.array([[1.0], [2.0], [5.5]], np.float32)
    # test 2: distances 4.5 (reference 1) and 5.5, ratio 0.82 fails the ratio test 0.7, yet reference 1's nearest
    # test is test 2 (4.5 < 8 < 9): mutual. Test 1 is nearest reference 0, which prefers test 0: not mutual.
    matches = MATCHERS.get("mutual_nn").build().index(reference, "l2").match(test)
    assert matches.tolist() == [[0, 0], [2, 1]]


def test_flann_ratio_test_uses_distances_not_squares():
    # 1-D: test 3.5 has distances 3.5 and 6.5 (squared 12.25, 42.25): 3.5 < 0.7 * 6.5 = 4.55 -> match;
    # with ratio 0.5: 3.5 > 3.25 -> none (on squares 12.25 < 0.5 * 42.25 would wrongly match)
    reference, test = np.array([[0.0], [10.0]], np.float32), np.array([[3.5]], np.float32)
    assert MATCHERS.get("flann").build().index(reference, "l2").match(test).tolist() == [[0, 0]]
    assert MATCHERS.get("flann").build({"ratio": 0.5}).index(reference, "l2").match(test).shape == (0, 2)


def test_flann_index_is_reproducible():
    test, reference = float_sets(n_ref=2000, seed=1)
    noisy = test + 0.2  # far from their references: approximate search with few checks depends on the trees
    matcher = MATCHERS.get("flann").build({"checks": 4, "ratio": 1.0})
    first = matcher.index(reference, "l2").match(noisy)
    assert np.array_equal(first, matcher.index(reference, "l2").match(noisy))


def test_too_few_references_or_tests_give_no_match():
    for name in MATCHERS:
        matcher = MATCHERS.get(name).build()
        if getattr(matcher, "needs_keypoints", False):
            continue  # LightGlue: tests/test_learned.py
        one = np.zeros((1, 8), np.float32)
        assert matcher.index(np.zeros((0, 8), np.float32), "l2").match(one).shape == (0, 2)
        assert matcher.index(np.zeros((5, 8), np.float32), "l2").match(np.zeros((0, 8), np.float32)).shape == (0, 2)


def test_forced_flann_index_on_the_other_norm_is_not_applicable():
    kdtree = MATCHERS.get("flann").build({"algorithm": "kdtree"})
    assert applicability(kdtree, "l2") is None
    assert "binary" in applicability(kdtree, "hamming")
    assert applicability(MATCHERS.get("bf_ratio").build(), "hamming") is None
    with pytest.raises(NotApplicable, match="KDTREE|L2"):
        kdtree.index(np.zeros((4, 32), np.uint8), "hamming")
    assert "real-valued" in applicability(MATCHERS.get("flann").build({"algorithm": "lsh"}), "l2")


def test_registry_params_are_strict_and_checked():
    assert MATCHERS.get("bf_ratio").params() == {"ratio": 0.7, "mutual": False}
    assert MATCHERS.get("flann").params({"trees": 8})["trees"] == 8
    with pytest.raises(BadInput, match="has no parameter 'k'; its parameters: mutual, ratio"):
        MATCHERS.get("bf_ratio").params({"k": 3})
    with pytest.raises(BadInput, match="has no parameter 'ratio'"):
        MATCHERS.get("mutual_nn").params({"ratio": 0.8})
    with pytest.raises(BadInput, match="should be int"):
        MATCHERS.get("flann").params({"trees": "many"})
    with pytest.raises(BadInput, match="ratio must be a number in \\(0, inf\\), got 0"):
        MATCHERS.get("bf_ratio").check({"ratio": 0})
    with pytest.raises(BadInput, match="key_size must be an integer in \\[1, 31\\], got 40"):
        MATCHERS.get("flann").check({"key_size": 40})
    with pytest.raises(BadInput, match="algorithm must be one of auto, kdtree, lsh"):
        MATCHERS.get("flann").check({"algorithm": "linear"})
    with pytest.raises(UnknownMethod,
                       match="unknown matcher 'knn'; valid choices: bf_ratio, flann, lightglue, mutual_nn"):
        MATCHERS.get("knn")
