"""dataset=survey: capture physics keeps ground truth exact, optimisation views never see test ground, the revisit
law has the survey's mean, rendering is deterministic."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import yaml

from gtsweep.core.errors import BadInput
from gtsweep.core.paths import CONF_DIR
from gtsweep.datasets import capture, floors, geometry, layout, synthetic
from gtsweep.datasets import options as opts
from gtsweep.datasets.__main__ import revisit_line

SURVEY = yaml.safe_load((CONF_DIR / "dataset" / "survey.yaml").read_text())
#: Every per-frame effect neutral: fixed exposure filling the well, no motion, light or tilt; the sensor stays.
NEUTRAL = {"speed_m_s": 0.0, "exposure_ms": 1.0, "brightness_jitter": 0.0, "lens_vignetting": False,
           "light_falloff": 0.0, "light_gradient": 0.0, "tilt_deg": 0.0}


def survey_options(**changes) -> dict:
    """survey.yaml's options with ``changes``, checked as the loader does."""
    return synthetic.check(opts.read({**SURVEY, **changes}, synthetic.DEFAULTS, "synthetic"))


def small(tmp_path, frame, **changes) -> dict:
    """A small survey-like data set's raw options: incremental pairs of 320x240 tiles views."""
    return {**SURVEY, "textures": ["tiles"], "view_size": [320, 240], "n_optimisation": 0, "n_synthetic": 0,
            "n_incremental": 4, "n_absolute": 0, "cache_dir": str(tmp_path), "capture": frame, **changes}


def overlap_residual(dataset) -> float:
    """RMS gray-level difference between each incremental reference and its test warped onto it with the exact
    pose (pair.H), inside the common area (eroded by 8 px against border effects of the warp)."""
    errors = []
    for pair in dataset.pairs("incremental"):
        reference, test = pair.reference.load().astype(np.float32), pair.test.load().astype(np.float32)
        h, w = reference.shape
        warped = cv2.warpPerspective(test, pair.H, (w, h), flags=cv2.INTER_CUBIC)
        inside = cv2.warpPerspective(np.ones_like(test), pair.H, (w, h), flags=cv2.INTER_NEAREST)
        inside = cv2.erode(inside, np.ones((17, 17), np.uint8)) > 0
        errors.append((warped - reference)[inside] ** 2)
    return float(np.sqrt(np.concatenate(errors).mean()))


@pytest.mark.slow
def test_capture_effects_exceed_sensor_noise_and_vanish_when_off(tmp_path):
    off = synthetic.load(small(tmp_path, None, sensor_noise=0.0))
    noise_only = synthetic.load(small(tmp_path, NEUTRAL))
    tilt_only = synthetic.load(small(tmp_path, {**NEUTRAL, "tilt_deg": 1.5, "full_well_e": None,
                                                "read_noise_e": 0.0}))
    everything = synthetic.load(small(tmp_path, {}))
    residual = {name: overlap_residual(d) for name, d in
                (("off", off), ("noise", noise_only), ("tilt", tilt_only), ("all", everything))}
    print("overlap residual (gray levels RMS):", {k: round(v, 2) for k, v in residual.items()})
    assert residual["off"] < 1.0                          # only the bicubic resampling of both views
    assert residual["tilt"] < 1.0                         # tilt is in the pose: ground truth stays exact
    assert residual["noise"] > 1.5                        # shot + read noise of two frames
    assert residual["all"] > 2 * residual["noise"]        # blur, exposure, lighting, tilt perspective


def test_sensor_noise_follows_shot_and_read_noise():
    """Mid gray (128) at gain 1: 5020 e-, std sqrt(5020 + 12^2) e- = 71.9 e- = 1.83 gray levels."""
    options = {**capture.FRAME_DEFAULTS}
    params = {"exposure_ms": 1.0, "brightness": 1.0}
    image = capture.sensor(np.full((400, 400), 128.0, np.float32), np.random.default_rng(0), params, options)
    assert image.mean() == pytest.approx(128, abs=0.05)
    assert image.std() == pytest.approx(math.sqrt(128 / 255 * 10000 + 144) * 255 / 10000, rel=0.05)
    params["exposure_ms"] = 0.1  # gain 10: ten times fewer electrons, sqrt(10) x the relative noise
    assert capture.sensor(np.full((400, 400), 128.0, np.float32), np.random.default_rng(0), params,
                          options).std() == pytest.approx(math.sqrt(502 + 144) * 255 / 10000 * 10, rel=0.05)


def test_motion_kernel_blurs_along_travel_without_moving():
    kernel = capture.motion_kernel(6.25, 0.0)  # 1 ms at 1 m/s on Micro-GPS: 1 mm = 6.25 px
    assert kernel.sum() == pytest.approx(1.0)
    ys, xs = np.mgrid[0:kernel.shape[0], 0:kernel.shape[1]]
    centre = kernel.shape[0] // 2
    assert (kernel * xs).sum() == pytest.approx(centre, abs=1e-5)
    assert (kernel * ys).sum() == pytest.approx(centre, abs=1e-5)
    assert np.count_nonzero(kernel[centre]) >= 6 and kernel[centre + 1 :].sum() == 0
    assert capture.blur_length_px({"exposure_ms": 1.0, "speed_m_s": 1.0}, 6.25) == pytest.approx(6.25)


def test_tilt_is_the_rotation_homography():
    """A pixel seen along ray d by the tilted camera is seen along R d by the nadir one: K R K^-1, then one shift
    that keeps the image centre on its floor point."""
    focal, shape = 1562.5, (964, 1288)
    H = capture.tilt(1.5, -1.0, shape, focal)
    K = np.array([[focal, 0, 643.5], [0, focal, 481.5], [0, 0, 1.0]])
    rotation, _ = cv2.Rodrigues(np.radians([1.5, -1.0, 0.0]))
    rays = np.column_stack([np.random.default_rng(0).uniform(-0.4, 0.4, (20, 2)), np.ones(20)])
    tilted, nadir = rays @ K.T, rays @ (K @ rotation).T
    mapped = tilted @ H.T
    offsets = mapped[:, :2] / mapped[:, 2:] - nadir[:, :2] / nadir[:, 2:]
    assert np.ptp(offsets, axis=0) == pytest.approx([0, 0], abs=1e-6)  # one shift for every pixel
    centre = H @ np.array([643.5, 481.5, 1.0])
    assert centre[:2] / centre[2] == pytest.approx([643.5, 481.5])
    assert capture.tilt(0.0, 0.0, shape, focal) == pytest.approx(np.eye(3))
    reach = capture.tilt_reach_px(1.5, (1288, 964), focal)
    for pitch, roll in ((1.5, 1.5), (-1.5, 1.5), (1.5, -1.5), (-1.5, -1.5)):
        corners = geometry.footprint(capture.tilt(pitch, roll, shape, focal), shape)
        assert np.abs(corners - geometry.footprint(np.eye(3), shape)).max() <= reach


@pytest.mark.parametrize("name, textures", [
    ("survey", list(floors.FLOOR_TYPES)),                 # the six Micro-GPS types and the opt-in photos
    ("synthetic", list(floors.PROCEDURAL)),               # the photo floors of dataset=synthetic do share ground
])
def test_optimisation_footprints_never_meet_test_footprints(name, textures):
    raw = SURVEY if name == "survey" else yaml.safe_load((CONF_DIR / "dataset" / "synthetic.yaml").read_text())
    options = synthetic.check(opts.read({**raw, "textures": textures}, synthetic.DEFAULTS, "synthetic"))
    shape = options["view_size"][::-1]
    for texture in textures:
        side = synthetic.floor_side(texture, options)
        plan = layout.plan_floor(side, options["view_size"], float(options["scale_jitter"]),
                                 synthetic.reach_px(options), bool(options["separate_optimisation"]))
        views = synthetic.plan_texture(texture, options, plan)
        optimisation = [geometry.footprint(v["pose"], shape) for v in views if v["split"] == "optimisation"]
        others = [geometry.footprint(v["pose"], shape) for v in views if v["split"] != "optimisation"]
        assert len(optimisation) == options["n_optimisation"] and len(others) > 0
        for a in optimisation:
            for b in others:
                area, _ = cv2.intersectConvexConvex(cv2.convexHull(a), cv2.convexHull(b))
                assert area <= 0, f"{name}/{texture}: optimisation view meets a test view ({area:.0f} px^2)"
        inside = np.concatenate(optimisation + others)
        assert inside.min() >= 0 and inside.max() <= side - 1, "every footprint lies on the floor"


def test_photo_floors_of_synthetic_share_ground():
    """Known limit of dataset=synthetic (kept for its numbers): a 1536 px photo floor has no separate band."""
    options = synthetic.check(opts.read({"textures": ["gravel"]}, synthetic.DEFAULTS, "synthetic"))
    plan = layout.plan_floor(synthetic.floor_side("gravel", options), options["view_size"], 0.02)
    assert plan.optimisation_box == plan.main_box
    with pytest.raises(BadInput, match="separate optimisation band"):
        layout.plan_floor(synthetic.floor_side("gravel", options), options["view_size"], 0.02, 0.0, True)


def test_revisit_law_has_the_survey_mean():
    law = survey_options()["absolute"]
    same, opposite, crossing = layout.revisit_weights(law)
    assert same + opposite + crossing == pytest.approx(1.0)
    assert layout.revisit_mean(law) == pytest.approx(120.0, abs=1e-9)
    share = layout.revisit_share_below(law, 15.0)
    assert (same, opposite, share) == pytest.approx((0.1505, 0.5162, 0.158), abs=5e-4)
    drawn = np.abs(layout.rotation_targets(np.random.default_rng(0), 20000, law))
    print(f"revisit law: mean {drawn.mean():.2f} deg (analytic 120), share < 15 deg {np.mean(drawn < 15):.3f} "
          f"(analytic {share:.3f})")
    print(revisit_line(law))
    assert drawn.mean() == pytest.approx(120.0, abs=0.3)
    assert np.mean(drawn < 15) == pytest.approx(share, abs=0.01)
    assert drawn.max() <= 180.0
    with pytest.raises(BadInput, match="revisit law"):
        layout.revisit_weights({**law, "crossing": 0.0, "rotation_mean": 179.0})


@pytest.mark.slow
def test_survey_rendering_is_deterministic(tmp_path):
    frame = {}
    a = synthetic.load(small(tmp_path / "a", frame, n_absolute=1, n_optimisation=1, n_synthetic=1))
    b = synthetic.load(small(tmp_path / "b", frame, n_absolute=1, n_optimisation=1, n_synthetic=1))
    assert a.fingerprint() == b.fingerprint()
    pairs_a, pairs_b = a.pairs("incremental") + a.pairs("absolute"), b.pairs("incremental") + b.pairs("absolute")
    for p, q in zip(pairs_a, pairs_b):
        for s, t in ((p.reference, q.reference), (p.test, q.test)):
            assert np.array_equal(s.load(), t.load()) and np.array_equal(s.pose, t.pose)
    assert not np.array_equal(pairs_a[0].reference.load(), pairs_a[1].reference.load())


def test_survey_config_is_the_protocol():
    options = survey_options()
    assert options["view_size"] == (1288, 964) and options["textures"] == list(floors.PROCEDURAL)
    assert [options[f"n_{k}"] for k in ("optimisation", "synthetic", "incremental", "absolute")] == [3, 100, 100, 100]
    assert set(SURVEY["capture"]) == set(capture.FRAME_DEFAULTS) and set(SURVEY["day"]) == set(capture.DAY_DEFAULTS)
    assert synthetic.floor_side("wood", options) >= 4 * 1288
    with pytest.raises(BadInput, match="unknown capture key"):
        survey_options(capture={"shutter": 1})


def test_day_effects_and_the_frame_api():
    rng = np.random.default_rng(0)
    floor = np.random.default_rng(1).uniform(40, 200, (120, 160)).astype(np.float32)
    neutral = {"ambient": 0.0, "dust": 0.0, "wear": 0.0, "gamma": 1.0, "ambient_direction_deg": 0.0}
    assert np.array_equal(capture.day(floor, rng, neutral, 6.25), floor)
    lit = capture.day(floor, rng, {**neutral, "ambient": 0.2}, 6.25)
    edge = 79.5 / math.hypot(79.5, 59.5)  # the ramp runs from 0 to 1 between corners: 0.1 / 0.9 at the edges
    assert lit[:, -1] / floor[:, -1] == pytest.approx(1 + 0.2 * (0.5 + 0.5 * edge), rel=1e-5)
    assert lit[:, 0] / floor[:, 0] == pytest.approx(1 + 0.2 * (0.5 - 0.5 * edge), rel=1e-5)
    dusty = capture.day(floor, rng, {**neutral, "dust": 0.01}, 6.25)
    assert 0.002 < np.mean(dusty != floor) < 0.03
    params = capture.draw_day(np.random.default_rng(0), capture.DAY_DEFAULTS)
    assert 0.8 <= params["gamma"] <= 1.25 and 0 <= params["ambient"] <= 0.2
    image = capture.random_frame(floor, np.random.default_rng(0), capture.FRAME_DEFAULTS, 6.25)
    again = capture.random_frame(floor, np.random.default_rng(0), capture.FRAME_DEFAULTS, 6.25)
    assert image.dtype == np.uint8 and image.shape == floor.shape and np.array_equal(image, again)


def test_a_smaller_data_set_is_a_prefix_of_a_larger_one():
    """The sequential reproduction adds images and pairs per round: the views of n = 6 are the first views of
    n = 12 (same poses, capture and another-day parameters), so the keypoint cache serves them again."""
    small_counts, large_counts = (survey_options(n_synthetic=n, n_incremental=n, n_absolute=n) for n in (6, 12))
    floor = layout.plan_floor(synthetic.floor_side("tiles", small_counts), small_counts["view_size"], 0.02,
                              synthetic.reach_px(small_counts), True)
    small_views = synthetic.plan_texture("tiles", small_counts, floor)
    large_views = {v["id"]: v for v in synthetic.plan_texture("tiles", large_counts, floor)}
    assert len(large_views) > len(small_views) == 3 + 6 + 2 * 6 + 2 * 6
    for view in small_views:
        other = large_views[view["id"]]
        assert np.array_equal(view["pose"], other["pose"]), view["id"]
        assert view.get("params") == other.get("params") and view.get("frame") == other.get("frame")
        assert view.get("day") == other.get("day")
