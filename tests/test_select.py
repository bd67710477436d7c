"""Tests for gtsweep.stages.select (survey 2.2 / 5.1: NMS, ANMS via SSC, bucketing)."""
import numpy as np
import pytest
from scipy.spatial.distance import pdist

from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.stages.keypoints import COLUMNS, RESPONSE, X, Y
from gtsweep.stages.select import SELECTORS, select, select_anms, select_bucketing, select_nms, select_none

SHAPE = (480, 640)  # (height, width)


def make_keypoints(xy, response) -> np.ndarray:
    kps = np.zeros((len(xy), len(COLUMNS)))
    kps[:, [X, Y]] = xy
    kps[:, RESPONSE] = response
    return kps


def random_keypoints(count, seed=0, clustered=0) -> np.ndarray:
    """Uniform keypoints; the first ``clustered`` sit in a tight blob at (100, 100) and respond most strongly."""
    rng = np.random.default_rng(seed)
    xy = np.column_stack([rng.uniform(0, SHAPE[1], count), rng.uniform(0, SHAPE[0], count)])
    xy[:clustered] = np.clip(rng.normal(100, 5, (clustered, 2)), 0, 479)
    response = rng.integers(0, 100, count).astype(float)
    response[:clustered] += 1000
    return make_keypoints(xy, response)


def occupied_cells(kps, size=40) -> int:
    return len({(int(x // size), int(y // size)) for x, y in kps[:, [X, Y]]})


def test_none_sorts_by_response_with_stable_ties():
    kps = make_keypoints([[0, 0], [1, 1], [2, 2], [3, 3]], [5, 7, 5, 9])
    out = select_none(kps, SHAPE)
    # responses 9 (idx 3), 7 (idx 1), then the tie 5, 5 in detection order: idx 0 before idx 2
    assert out[:, X].tolist() == [3, 1, 0, 2]


def test_nms_keeps_top_n_by_response():
    kps = random_keypoints(500, seed=1)
    out = select_nms(kps, SHAPE, n=50)
    assert len(out) == 50
    assert np.all(np.diff(out[:, RESPONSE]) <= 0)
    # the 50th largest response bounds everything kept from below and everything dropped from above
    threshold = np.sort(kps[:, RESPONSE])[::-1][49]
    assert out[:, RESPONSE].min() == threshold
    assert np.sum(kps[:, RESPONSE] > threshold) <= 50


def test_nms_on_fewer_points_returns_all():
    kps = random_keypoints(10)
    assert len(select_nms(kps, SHAPE, n=1000)) == 10


def test_anms_count_within_tolerance():
    kps = random_keypoints(20000, seed=2)
    out = select_anms(kps, SHAPE, n=500, tolerance=0.2)
    # accepted range [round(500 - 100), round(500 + 100)] = [400, 600]
    assert 400 <= len(out) <= 600
    assert np.all(np.diff(out[:, RESPONSE]) <= 0)


def test_anms_spreads_better_than_nms_on_clustered_points():
    # 1500 strong keypoints in one blob, 5000 weaker ones spread uniformly: NMS takes 1000 from the blob
    kps = random_keypoints(6500, seed=3, clustered=1500)
    nms, anms = select_nms(kps, SHAPE, n=1000), select_anms(kps, SHAPE, n=1000)
    assert occupied_cells(nms) <= 4  # the blob (sd 5 px) spans only a few 40-px cells
    assert occupied_cells(anms) > 150  # of 16 x 12 = 192 cells
    # the strongest keypoint is always selected first by SSC
    assert np.array_equal(anms[0], select_nms(kps, SHAPE, n=1)[0])


def test_anms_picks_are_far_apart_unlike_nms():
    # each SSC pick covers the cells within +-2 cells (cell side width/2) of its own, so two picks differ by at
    # least 3 cells along x or y: their Chebyshev distance exceeds the final width. 200 picks on 640 x 480 leave
    # ~39 px spacing; NMS's top 200 of 5000 uniform points lie ~1 px apart at their closest.
    kps = random_keypoints(5000, seed=4)
    anms, nms = select_anms(kps, SHAPE, n=200), select_nms(kps, SHAPE, n=200)
    assert pdist(anms[:, [X, Y]], "chebyshev").min() > 10
    assert pdist(anms[:, [X, Y]], "chebyshev").min() > 5 * pdist(nms[:, [X, Y]], "chebyshev").min()


def test_anms_on_fewer_points_than_n_returns_all_sorted():
    kps = random_keypoints(300, seed=5)
    out = select_anms(kps, SHAPE, n=1000)
    assert len(out) == 300
    assert np.array_equal(out, select_none(kps, SHAPE))


def test_anms_single_keypoint_request_does_not_divide_by_zero():
    kps = random_keypoints(1000, seed=6)
    out = select_anms(kps, SHAPE, n=1)
    # K = 1: range [round(0.8), round(1.2)] = [1, 1]; the pick is the strongest keypoint
    assert len(out) == 1
    assert out[0, RESPONSE] == kps[:, RESPONSE].max()


def test_anms_matches_hand_worked_small_case():
    # 4 keypoints in a 100 x 100 image, n = 2, tolerance 0 -> exactly 2 wanted.
    # low = floor(sqrt(4 / 2)) = 1; high: exp1 = 204, exp2 = 4*100 + 8 + 800 + 10000 + 10000 - 20000 + 80000
    # = 81208, sqrt = 284.97, roots -round(488.97) and -round(-80.97) = 81 -> high = 81.
    # Pass 1: width 41, cells of 20.5 px, 5 x 5 grid. (10,10) in cell (0,0) covers cells 0..2 x 0..2; (20,20) is
    # covered; (90,90) in cell (4,4) is free; (95,10) in cell (col 4, row 0) is free -> 3 picks, too many.
    # Pass 2: low = 42, width 61, cells of 30.5 px. (10,10) covers cells 0..2 x 0..2 (up to 91.5 px), which
    # holds (20,20) and (90,90); (95,10) in col 3 is free -> picks (10,10), (95,10): 2, accepted.
    kps = make_keypoints([[10, 10], [20, 20], [90, 90], [95, 10]], [4, 3, 2, 1])
    out = select_anms(kps, (100, 100), n=2, tolerance=0.0)
    assert out[:, X].tolist() == [10, 95]


def test_bucketing_respects_per_cell_and_total_limits():
    kps = random_keypoints(20000, seed=7, clustered=2000)
    out = select_bucketing(kps, SHAPE, rows=8, cols=6, per_cell=21)
    assert len(out) <= 8 * 6 * 21  # 1008
    row = np.floor(out[:, Y] * 8 / SHAPE[0]).astype(int)
    col = np.floor(out[:, X] * 6 / SHAPE[1]).astype(int)
    counts = np.bincount(row * 6 + col, minlength=48)
    assert counts.max() <= 21
    assert np.all(np.diff(out[:, RESPONSE]) <= 0)
    # 20000 points over 48 cells: every cell holds far more than 21, so all are full
    assert len(out) == 1008


def test_bucketing_keeps_strongest_in_each_cell():
    # one 2 x 1 grid on a 100 x 100 image, 2 per cell; left cell responses 1,5,3 -> keeps 5,3; right 9 -> keeps 9
    kps = make_keypoints([[10, 10], [20, 20], [30, 30], [80, 50]], [1, 5, 3, 9])
    out = select_bucketing(kps, (100, 100), rows=1, cols=2, per_cell=2)
    assert out[:, RESPONSE].tolist() == [9, 5, 3]


@pytest.mark.parametrize("name", sorted(SELECTORS))
def test_selectors_are_deterministic(name):
    kps = random_keypoints(8000, seed=8, clustered=500)
    first, second = select(kps, name, SHAPE), select(kps.copy(), name, SHAPE)
    assert first.tobytes() == second.tobytes()


def test_unknown_selector_raises():
    with pytest.raises(UnknownMethod, match="unknown selector 'foo'; valid choices: anms, bucketing, nms, none"):
        select(random_keypoints(5), "foo", SHAPE)


@pytest.mark.parametrize(
    "call",
    [
        lambda: select(np.zeros((3, 2)), "nms", SHAPE),
        lambda: select(random_keypoints(5), "nms", SHAPE, n=0),
        lambda: select(random_keypoints(5), "nms", SHAPE, n=2.5),
        lambda: select(random_keypoints(5), "anms", SHAPE, tolerance=1.5),
        lambda: select(random_keypoints(5), "bucketing", (0, 10)),
        lambda: select(random_keypoints(5), "nms", SHAPE, rows=3),
    ],
)
def test_bad_input_raises_one_line(call):
    with pytest.raises(BadInput) as info:
        call()
    assert "\n" not in str(info.value)


def test_empty_input_gives_empty_output():
    empty = np.zeros((0, len(COLUMNS)))
    for name in SELECTORS:
        assert select(empty, name, SHAPE).shape == (0, len(COLUMNS))
