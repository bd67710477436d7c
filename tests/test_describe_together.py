"""A descriptor that can describe keypoint sets together (``together``: DAISY, whose cost is a pass over the image;
SIFT, whose pyramid depends only on the lowest octave) describes every detector's keypoints of an image, and every
reference count, in one call per group (issue 25: a repeated per-image pass): the descriptors are those of separate
calls, bit for bit, and a sweep's cells are the same with ``runner.describe_together`` on or off."""
import numpy as np
import pytest

from gtsweep.core.errors import GtsweepError
from gtsweep.evaluation.reuse import describe_together
from gtsweep.experiments.kinds import run_sweep
from gtsweep.stages import describe as describe_stage
from gtsweep.stages import keypoints as kp
from gtsweep.stages.describe import DESCRIPTORS, describe_batch, describe_timed
from gtsweep.stages.detect import detect
from sweep_helpers import assert_same_cells, compose_config, tiny_overrides


@pytest.fixture(scope="module")
def keypoint_sets(gravel_small):
    """Three detectors' keypoints of one image: SIFT's and AKAZE's own octaves, ORB's pyramid levels."""
    def strongest(name):
        found = detect(gravel_small, name)
        return found[np.argsort(-found[:, kp.RESPONSE], kind="stable")[:150]]
    return {name: strongest(name) for name in ("sift", "akaze", "orb")}


def test_one_daisy_call_gives_each_detectors_descriptors_of_separate_calls(gravel_small, keypoint_sets):
    assert DESCRIPTORS.get("daisy").together == "image" and DESCRIPTORS.get("brief").together is None
    requests = list(keypoint_sets.items()) + [("orb", keypoint_sets["orb"][:10]), ("sift", keypoint_sets["sift"][:0])]
    together = describe_batch(gravel_small, requests, "daisy")
    for (detector, keypoints), (kept, desc, seconds) in zip(requests, together):
        alone_kept, alone_desc, _ = describe_timed(gravel_small, keypoints, "daisy", detector)
        assert np.array_equal(kept, alone_kept) and desc.tobytes() == alone_desc.tobytes() and desc.dtype == np.float32
        assert len(desc) == len(keypoints) and (seconds > 0) == (len(keypoints) > 0)
    shares = {round(seconds, 12) for _, _, seconds in together if seconds}
    assert len(shares) == 1  # the call's time shared equally by the sets it served


def test_sift_describes_sets_together_per_first_octave_as_separate_calls_do(gravel_small, keypoint_sets):
    """SIFT builds its pyramid from the lowest octave it is given (-1: the image upsampled): its own keypoints
    (octaves from -1) and ORB's and AKAZE's (at their own scale: from 0 here) take two calls, each equal to
    separate calls bit for bit."""
    from gtsweep.stages.describe import TOGETHER, prepare_keypoints

    spec = DESCRIPTORS.get("sift")
    firsts = {d: TOGETHER["first_octave"](prepare_keypoints(k, d, spec, spec.build({}), gravel_small.shape))
              for d, k in keypoint_sets.items()}
    assert firsts["sift"] == -1 and {firsts["orb"], firsts["akaze"]} == {0}
    requests = list(keypoint_sets.items())
    together = describe_batch(gravel_small, requests, "sift")
    for (detector, keypoints), (kept, desc, _) in zip(requests, together):
        alone_kept, alone_desc, _ = describe_timed(gravel_small, keypoints, "sift", detector)
        assert np.array_equal(kept, alone_kept) and desc.tobytes() == alone_desc.tobytes()
    assert together[1][2] == together[2][2] != together[0][2]  # akaze and orb shared one call, sift had its own


def test_a_descriptor_that_drops_keypoints_cannot_describe_them_together(gravel_small, keypoint_sets,
                                                                       monkeypatch):
    """BRISK drops keypoints near the border: declared ``together``, one call for several sets could not be
    split back, and says so."""
    import dataclasses

    brisk = dataclasses.replace(DESCRIPTORS.get("brisk"), together="image")
    monkeypatch.setattr(describe_stage.DESCRIPTORS, "get", lambda name: brisk)
    border = keypoint_sets["orb"].copy()
    border[:5, 0] = 2.0
    with pytest.raises(GtsweepError, match="kept .* of .* keypoints"):
        describe_batch(gravel_small, [("orb", border), ("orb", keypoint_sets["orb"])], "brisk")


def test_the_memos_hold_every_description_asked_for_with_one_call_per_image(gravel_small, keypoint_sets,
                                                                            monkeypatch):
    calls = []
    batch = describe_stage.describe_batch
    monkeypatch.setattr("gtsweep.evaluation.reuse.describe_batch",
                        lambda image, requests, *a, **k: calls.append(len(requests)) or batch(image, requests, *a, **k))
    other = np.ascontiguousarray(gravel_small[::-1])
    asked = [(d, [(gravel_small, k), (gravel_small, k[:50]), (other, k)]) for d, k in keypoint_sets.items()]
    asked.append(("orb", [(gravel_small, keypoint_sets["orb"][::2])]))  # ORB again, under another selector
    asked.append(("gftt", [(gravel_small, keypoint_sets["orb"])]))  # DAISY needs oriented keypoints: NA
    memos = describe_together(asked, "daisy", {})
    assert calls == [7, 3]  # one call per image: 3 detectors x 2 counts and the second ORB member, then 3
    for (detector, pairs), memo in zip(asked, memos):
        if detector == "gftt":
            continue
        for image, keypoints in pairs:
            kept, desc, _ = memo.describe(image, keypoints)
            assert desc.tobytes() == describe_timed(image, keypoints, "daisy", detector)[1].tobytes()
        assert memo.computed == 0  # every description came from the one call per image
    (brief,) = describe_together([("orb", [(gravel_small, keypoint_sets["orb"])])], "brief", {})
    assert brief.computed == 0 and brief.describe(gravel_small, keypoint_sets["orb"]) and brief.computed == 1
    assert calls == [7, 3]  # a descriptor without together: nothing described ahead


def test_a_sweep_with_daisy_gives_the_same_cells_together_or_apart(tmp_path):
    """Three oriented detectors and an unoriented one (NA for DAISY; GFTT's small keypoints take SIFT's upsampled
    pyramid) under two selectors, on real pairs and a synthetic transform, with survey Table 7's reference counts:
    the cells are identical to those of separate calls (``runner.describe_together=false``), and together needs
    fewer pairing tasks."""
    grid = ["detector=[akaze,sift,orb,gftt]", "descriptor=[daisy,brief,sift]", "selector=[nms,anms]",
            "transform=[incremental,rotation]", "transform.rotation.strengths=[0,90]",
            "experiment.reference_counts=[50,150]", "runner.backend=serial", "mlflow.enabled=false",
            "report.plots=false", "dataset.textures=[gravel]"]  # one texture: the groups are per image
    apart = run_sweep(compose_config(tiny_overrides(tmp_path, *grid, "runner.describe_together=false")),
                      tmp_path / "apart")
    together = run_sweep(compose_config(tiny_overrides(tmp_path, *grid)), tmp_path / "together")
    assert_same_cells(tmp_path / "apart", tmp_path / "together")
    daisy = [s for s in together.summaries if s["methods"]["descriptor"] == "daisy"]
    assert {s["status"] for s in daisy} == {"ok", "na"}
    # per (transform, shard): DAISY's 3 applicable detectors under 2 selectors share one pairing task, SIFT's 4
    assert apart.stats.pairing_tasks - together.stats.pairing_tasks == (5 + 7) * (apart.stats.detection_tasks // 8)


def test_a_set_that_cannot_be_prepared_is_left_to_its_own_call(gravel_small, keypoint_sets):
    """Under the survey's pass-through, MSD-like octaves (12) are no SIFT octave: that set comes back None (its
    own call raises the one-line reason), the others are described together as before."""
    msd_like = keypoint_sets["orb"][:20].copy()
    msd_like[:, kp.OCTAVE] = 12
    requests = [("akaze", keypoint_sets["akaze"]), ("msd", msd_like), ("orb", keypoint_sets["orb"])]
    together = describe_batch(gravel_small, requests, "sift", "passthrough")
    assert together[1] is None
    with pytest.raises(GtsweepError, match="passthrough: octaves 12"):
        describe_timed(gravel_small, msd_like, "sift", "msd", "passthrough")
    for (detector, keypoints), result in zip(requests[::2], together[::2]):
        assert result[1].tobytes() == describe_timed(gravel_small, keypoints, "sift", detector,
                                                     "passthrough")[1].tobytes()


def test_a_crashed_group_task_runs_each_detector_by_itself(tmp_path, monkeypatch):
    """A group task that dies (its worker, or one member's detection task) costs no cell: each detector's
    pairing job runs again by itself, as without groups, and the cells equal those of a run without groups."""
    from gtsweep.experiments.pairs import tasks

    grid = ["detector=[akaze,sift]", "descriptor=[sift]", "selector=[nms]", "transform=[incremental]",
            "runner.backend=serial", "mlflow.enabled=false", "report.plots=false"]
    apart = run_sweep(compose_config(tiny_overrides(tmp_path, *grid, "runner.describe_together=false")),
                      tmp_path / "apart")

    real = tasks.pair_shard_members

    def crash_in_groups(shard, transform, transform_cfg, detectors, *rest):
        if len(detectors) > 1:
            raise MemoryError("the worker died")
        return real(shard, transform, transform_cfg, detectors, *rest)
    monkeypatch.setattr(tasks, "pair_shard_members", crash_in_groups)
    crashed = run_sweep(compose_config(tiny_overrides(tmp_path, *grid)), tmp_path / "crashed")
    assert [s["status"] for s in crashed.summaries] == ["ok", "ok"]
    assert_same_cells(tmp_path / "apart", tmp_path / "crashed")
    groups = apart.stats.detection_tasks // 2
    assert crashed.stats.pairing_tasks == groups + apart.stats.pairing_tasks  # each group, then its jobs alone
