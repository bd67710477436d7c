"""Ratio-test and mutual matching, with answers worked out by hand."""
import numpy as np
import pytest

from gtsweep.core.errors import UnknownMethod
from gtsweep.stages.match import match_descriptors


def test_l2_ratio_test_by_hand():
    reference = np.array([[0, 0], [10, 0], [0, 10]], np.float32)
    test = np.array([[1, 0],     # distances 1, 9, sqrt(101)=10.05 -> 1 < 0.7*9: match 0
                     [5, 0],     # distances 5, 5 -> ratio 1: rejected
                     [0, 8]],    # distances 2 (to [0,10]), 8 (to [0,0]) -> 2 < 5.6: match 2
                    np.float32)
    assert match_descriptors(test, reference, "l2").tolist() == [[0, 0], [2, 2]]


def test_hamming_ratio_test_by_hand():
    reference = np.array([[0b00000000], [0b11111111]], np.uint8)
    test = np.array([[0b00000001],   # distances 1 and 7 -> 1 < 4.9: match 0
                     [0b00001111]],  # distances 4 and 4 -> rejected
                    np.uint8)
    assert match_descriptors(test, reference, "hamming").tolist() == [[0, 0]]


def test_ratio_threshold_is_strict():
    reference = np.array([[0.0], [10.0]], np.float32)
    test = np.array([[3.5]], np.float32)  # distances 3.5 and 6.5: 3.5 < 0.7*6.5 = 4.55 -> match; ratio 0.5 -> no
    assert len(match_descriptors(test, reference, "l2", ratio=0.7)) == 1
    assert len(match_descriptors(test, reference, "l2", ratio=0.5)) == 0


def test_too_few_reference_descriptors_give_no_match():
    assert match_descriptors(np.zeros((3, 4), np.float32), np.zeros((1, 4), np.float32), "l2").shape == (0, 2)
    with pytest.raises(UnknownMethod):
        match_descriptors(np.zeros((3, 4), np.float32), np.zeros((3, 4), np.float32), "cosine")


def test_mutual_nearest_neighbours_by_hand():
    reference = np.array([[0.0], [10.0]], np.float32)
    test = np.array([[1.0],    # nearest reference 0 (1 vs 9); reference 0's nearest test is this one: mutual
                     [2.0],    # nearest reference 0 too, but reference 0 prefers test 0: not mutual
                     [8.0]],   # nearest reference 1 (2 vs 8); reference 1's nearest test is this one: mutual
                    np.float32)
    # ratio test off (1.0): every test descriptor keeps its nearest neighbour
    assert match_descriptors(test, reference, "l2", ratio=1.0).tolist() == [[0, 0], [1, 0], [2, 1]]
    assert match_descriptors(test, reference, "l2", ratio=1.0, mutual=True).tolist() == [[0, 0], [2, 1]]
    # ratio 0.7: test 1 (distances 2 and 8, 2 < 5.6) passes the ratio test; mutual still removes it
    assert match_descriptors(test, reference, "l2", ratio=0.7).tolist() == [[0, 0], [1, 0], [2, 1]]
    assert match_descriptors(test, reference, "l2", ratio=0.7, mutual=True).tolist() == [[0, 0], [2, 1]]


def test_mutual_matching_of_binary_descriptors_and_a_single_reference():
    reference = np.array([[0b00000000]], np.uint8)
    test = np.array([[0b00000011], [0b00000001]], np.uint8)  # distances 2 and 1: reference 0 prefers test 1
    assert match_descriptors(test, reference, "hamming").shape == (0, 2)  # the ratio test needs 2 references
    assert match_descriptors(test, reference, "hamming", ratio=1.0, mutual=True).tolist() == [[1, 0]]
