"""Learned methods on a GPU, tested without one: ``runner.device`` resolution, the device in cell hashes and
keypoint-cache keys (CPU ones pinned as they were before devices), Ray's ``num_gpus``, and the written GPU-vs-CPU
tolerance (gtsweep.stages.gpu_tolerance) on a CPU device and on simulated device deviations."""
from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from gtsweep.cli.overrides import compose_config
from gtsweep.core.errors import BadInput
from gtsweep.experiments.pairs import runner
from gtsweep.experiments.pairs.grid import Cell, Grid, build_grid
from gtsweep.orchestration.cache import detection_key, detector_key_config
from gtsweep.orchestration.executor import RayExecutor, SerialExecutor
from gtsweep.orchestration.shards import shard_kind
from gtsweep.stages import device as devices
from gtsweep.stages import gpu_tolerance as tolerance

VERSIONS = {"opencv": "5.0.0", "numpy": "2.4.6", "gtsweep": "source", "surf": "gtsweep-numpy"}
CELLS = [Cell("aliked_n16rot", "nms", "aliked_n16rot", "absolute", None, "lightglue", "ransac"),
         Cell("aliked_n16rot", "nms", "sift", "absolute", None, "bf_ratio", "ransac"),
         Cell("sift", "nms", "sift", "absolute", None, "bf_ratio", "ransac")]
#: Cell hashes and detection keys computed before runner.device existed: a CPU run must keep them.
PINNED_CELL_HASHES = ["75887564b06e12cd", "9d8102e25153bdba", "2e695f81ac8b45e0"]
PINNED_DETECTION_KEYS = {
    "aliked_n16rot": "b22b912e96245894ccebb3522aac36fa4c8e2dd8eb9f74134789c560c099ef1c",
    "sift": "0110b22dd354f997861d5b1ee97d5c4d666222d0562fc5b87122d6ac0630a964",
}


def small_grid(device: str = "cpu") -> Grid:
    return Grid(experiment={"name": "pose", "ratio": 0.8},
                detectors={"aliked_n16rot": {"params": {"max_num_keypoints": 1000}},
                           "sift": {"params": {"nfeatures": 0}}},
                selectors={"nms": {"params": {"n": 1000}}},
                descriptors={"aliked_n16rot": {"params": {}}, "sift": {"params": {"sigma": 1.6}}},
                transforms={"absolute": {"strengths": [1]}},
                matchers={"bf_ratio": {"params": {}}, "lightglue": {"params": {"filter_threshold": 0.1}}},
                estimators={"ransac": {"params": {}}}, device=device)


def key_of(detector: str) -> str:
    image = (np.arange(48 * 64) % 251).astype(np.uint8).reshape(48, 64)
    params = small_grid().detectors[detector]["params"]
    return detection_key(image, None, detector, detector_key_config(detector, params), "nms",
                         {"params": {"n": 1000}}, VERSIONS)


@pytest.fixture
def cuda(monkeypatch):
    """A machine where torch sees CUDA (mocked: nothing runs on it here)."""
    monkeypatch.setattr(devices, "cuda_available", lambda: True)
    monkeypatch.setattr(devices, "full_precision_cuda", lambda: None)


# -- runner.device -------------------------------------------------------------------------------------------------

def test_auto_is_cpu_without_cuda_and_cuda_with_it(monkeypatch):
    monkeypatch.setattr(devices, "cuda_available", lambda: False)
    assert devices.resolve("auto") == devices.resolve(None) == "cpu"
    with pytest.raises(BadInput, match="runner.device=cuda, but torch sees no CUDA device"):
        devices.resolve("cuda")
    with pytest.raises(BadInput, match="runner.device must be one of auto, cpu, cuda, got 'gpu'"):
        devices.resolve("gpu")
    monkeypatch.setattr(devices, "cuda_available", lambda: True)
    assert devices.resolve("auto") == devices.resolve("cuda") == "cuda"
    assert devices.resolve("cpu") == "cpu"
    assert devices.resolve("cuda", needs_torch=False) == "cpu"  # no torch method: nothing to move


def test_the_setting_is_checked_with_the_other_run_settings():
    with pytest.raises(BadInput, match="runner.device"):
        build_grid(compose_config(["sweeps=smoke", "detector=[sift]", "runner.device=tpu"]))
    with pytest.raises(BadInput, match="runner.gpus_per_task"):
        build_grid(compose_config(["sweeps=smoke", "detector=[sift]", "runner.gpus_per_task=0"]))


def test_a_grid_without_torch_methods_stays_on_the_cpu(cuda):
    grid = build_grid(compose_config(["sweeps=smoke", "detector=[sift]", "descriptor=[sift]", "runner.device=auto"]))
    assert grid.device == "cpu" and not grid.torch_methods()


def test_using_sets_the_device_of_the_enclosed_work_and_restores_it(cuda):
    assert devices.current() == "cpu"
    with devices.using("cuda"):
        assert devices.current() == "cuda"
        with devices.using(None):
            assert devices.current() == "cpu"
        assert devices.current() == "cuda"
    assert devices.current() == "cpu"
    with pytest.raises(BadInput, match="a task's device must be cpu or cuda"):
        with devices.using("auto"):
            pass


# -- hashes and keys -----------------------------------------------------------------------------------------------

def test_cpu_cell_hashes_and_cache_keys_are_the_ones_from_before_devices():
    grid = small_grid("cpu")
    assert [grid.cell_hash(cell, "fingerprint", 0) for cell in CELLS] == PINNED_CELL_HASHES
    assert {name: key_of(name) for name in PINNED_DETECTION_KEYS} == PINNED_DETECTION_KEYS
    assert detector_key_config("aliked_n16rot", {"a": 1}) == {"params": {"a": 1}}


def test_cuda_changes_the_hashes_and_keys_of_the_methods_it_moves_only(cuda):
    grid = small_grid("cuda")
    hashes = [grid.cell_hash(cell, "fingerprint", 0) for cell in CELLS]
    # ALIKED cells (detector, descriptor or LightGlue on the GPU) get new hashes; SIFT with bf_ratio does not move.
    assert hashes[0] != PINNED_CELL_HASHES[0] and hashes[1] != PINNED_CELL_HASHES[1]
    assert hashes[2] == PINNED_CELL_HASHES[2]
    assert grid.cell_config(CELLS[0], "fingerprint", 0)["device"] == "cuda"
    with devices.using("cuda"):
        assert key_of("aliked_n16rot") != PINNED_DETECTION_KEYS["aliked_n16rot"]
        assert key_of("sift") == PINNED_DETECTION_KEYS["sift"]
        assert detector_key_config("disk", {}) == {"params": {}, "device": "cuda"}


# -- Ray resources -------------------------------------------------------------------------------------------------

class RecordingExecutor:
    """Records each submitted task's function and GPU share; handles are plain objects."""

    def __init__(self):
        self.submitted: list[tuple[str, tuple, float]] = []

    def put(self, value):
        return value

    def submit(self, function, *args, tag=None, num_returns=1, num_gpus=0.0):
        names = (args[3]["detector"],) if function.__name__ == "detect_shard" else (args[4], args[5])
        self.submitted.append((function.__name__, names, num_gpus))
        return tuple(object() for _ in range(num_returns)) if num_returns > 1 else object()


@pytest.mark.parametrize("device, share", [("cuda", 0.25), ("cpu", 0.0)])
def test_learned_tasks_ask_ray_for_a_gpu_share_when_the_device_is_cuda(cuda, device, share):
    cfg = compose_config(["sweeps=smoke", "detector=[aliked_n16rot,sift]", "descriptor=[aliked_n16rot,sift]",
                          "matcher=[bf_ratio,lightglue]", f"runner.device={device}", "mlflow.enabled=false"])
    grid = build_grid(cfg)
    assert grid.device == device
    kinds = {shard_kind(name, node) for name, node in grid.transforms.items()}
    jobs = runner.plan(grid, {kind: 1 for kind in kinds}, {cell.key for cell in grid.cells})
    executor = RecordingExecutor()
    runner.submit(executor, grid, {kind: [{}] for kind in kinds}, jobs, 0, None, False, 0.25)
    detections = {names[0]: gpus for name, names, gpus in executor.submitted if name == "detect_shard"}
    pairings = {names: gpus for name, names, gpus in executor.submitted if name == "pair_shard"}
    assert detections == {"aliked_n16rot": share, "sift": 0.0}
    assert pairings[("aliked_n16rot", "aliked_n16rot")] == share  # ALIKED describes (and LightGlue matches)
    assert pairings[("sift", "aliked_n16rot")] == share
    assert pairings[("aliked_n16rot", "sift")] == 0.0  # SIFT describes, bf_ratio matches: CPU work


def test_ray_options_carry_the_gpu_share_and_the_serial_executor_ignores_it():
    ray_executor = SimpleNamespace(retries=3)
    assert RayExecutor.resources(ray_executor, 2, 0.25) == {"num_cpus": 1, "num_returns": 2, "max_retries": 3,
                                                             "num_gpus": 0.25}
    assert "num_gpus" not in RayExecutor.resources(ray_executor, 1, 0.0)
    serial = SerialExecutor()
    handle = serial.submit(lambda: devices.current(), tag="t", num_gpus=0.5)
    assert dict(serial.results()) == {"t": "cpu"} and handle.task.error is None


def test_a_learned_method_built_on_cuda_puts_its_network_there(cuda, monkeypatch):
    from gtsweep.stages import learned

    loaded = []
    monkeypatch.setattr(learned, "load_aliked", lambda *args: loaded.append(args) or SimpleNamespace())
    with devices.using("cuda"):
        feature = learned.Aliked("aliked-n16rot")
    assert feature.device == "cuda" and loaded[-1][-1] == "cuda"
    assert learned.Aliked("aliked-n16rot").device == "cpu" and loaded[-1][-1] == "cpu"


# -- the tolerance -------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def texture() -> np.ndarray:
    noise = np.random.default_rng(1).random((200, 260)).astype(np.float32)
    mixed = cv2.GaussianBlur(noise, (0, 0), 1.0) + 2 * cv2.GaussianBlur(noise, (0, 0), 3.0)
    return cv2.normalize(mixed, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def test_a_cpu_device_run_agrees_with_the_default_run_exactly(texture):
    from gtsweep.stages.learned import DETECTIONS, ALIKED_create

    DETECTIONS.clear()
    default = ALIKED_create("aliked-n16rot", max_num_keypoints=300).detect_arrays(texture)
    DETECTIONS.clear()
    with devices.using("cpu"):
        on_device = ALIKED_create("aliked-n16rot", max_num_keypoints=300).detect_arrays(texture)
    agreement = tolerance.compare(default.xy, on_device.xy, default.descriptors, on_device.descriptors)
    np.testing.assert_array_equal(on_device.xy, default.xy)
    np.testing.assert_array_equal(on_device.descriptors, default.descriptors)
    assert agreement.keypoints == (300, 300) and agreement.matched_share == 1.0 and agreement.passed
    assert agreement.min_cosine == pytest.approx(1.0, abs=1e-12)


def test_the_tolerance_accepts_last_bit_deviations_and_rejects_larger_ones():
    # 1000 keypoints at least 3 px apart, as after non-maximum suppression
    rng = np.random.default_rng(7)
    gx, gy = np.meshgrid(np.arange(40) * 5.0, np.arange(25) * 5.0)
    xy = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-1, 1, (1000, 2))
    desc = rng.normal(size=(1000, 128)).astype(np.float32)
    noise = 1e-4 * rng.normal(size=desc.shape)
    near = tolerance.compare(xy, xy + rng.uniform(-0.3, 0.3, xy.shape), desc, desc + noise)
    assert near.passed and near.matched_share == 1.0 and near.min_cosine > 0.9999
    # 11 keypoints moved by 0.6 px (1.1 % of 1000): below the 99 % share
    moved = xy.copy()
    moved[:11] += 0.6
    shifted = tolerance.compare(xy, moved)
    assert shifted.matched_share == pytest.approx(0.989) and not shifted.passed
    # 10 keypoints missing and 10 others in their place: 990 of 1000 matched, exactly the share
    swapped = np.concatenate([xy[10:], xy[:10] + 50.0])
    assert tolerance.compare(xy, swapped).matched_share == pytest.approx(0.99)
    # one descriptor at cosine 0.99 fails the run
    unit = desc[3] / np.linalg.norm(desc[3])
    across = np.eye(128)[0] - unit[0] * unit
    bent = desc.copy()
    bent[3] = 0.99 * unit + np.sqrt(1 - 0.99 ** 2) * across / np.linalg.norm(across)
    assert tolerance.cosines(desc[3:4], bent[3:4])[0] == pytest.approx(0.99)
    assert not tolerance.compare(xy, xy, desc, bent).passed
    assert tolerance.same_positions(desc, desc) == pytest.approx(1.0)


def test_mutual_pairs_need_both_directions_and_the_radius():
    a = np.array([[0.0, 0.0], [10.0, 0.0]])
    b = np.array([[0.2, 0.0], [0.3, 0.0], [10.6, 0.0]])
    rows_a, rows_b = tolerance.mutual_pairs(a, b)
    assert rows_a.tolist() == [0] and rows_b.tolist() == [0]  # (10, 0) is 0.6 px from its neighbour


def test_pose_verdicts_must_be_the_same_for_every_pair():
    assert tolerance.same_verdicts([True, False, True], [1, 0, 1])
    assert not tolerance.same_verdicts([True, False], [True, True])
    assert not tolerance.same_verdicts([True], [True, False])


def test_cuda_without_a_device_stops_in_the_preflight_before_any_output(monkeypatch):
    from gtsweep.cli.overrides import compose_config  # the checks of a composed job, as the command line's

    monkeypatch.setattr(devices, "cuda_available", lambda: False)
    with pytest.raises(BadInput, match="runner.device=cuda, but torch sees no CUDA device"):
        compose_config(["sweeps=smoke", "detector=[aliked_n16rot]", "descriptor=[aliked_n16rot]",
                        "runner.device=cuda"])
    compose_config(["sweeps=smoke", "detector=[sift]", "descriptor=[sift]", "runner.device=cuda"])  # nothing moves
