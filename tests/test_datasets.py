"""The embedded default data set: exact ground truth, determinism, cache reuse, the survey's pair statistics,
floor layout, photometric changes, texture character, and the stats command."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import yaml

import dataset_fixtures as fx
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.paths import CONF_DIR
from gtsweep.datasets import __main__ as stats_command
from gtsweep.datasets import floors, geometry, layout, load_dataset, overlap, photometric, rotation_deg, synthetic

SMALL = {"loader": "synthetic", "textures": ["concrete", "gravel"], "view_size": [160, 120],
         "n_optimisation": 1, "n_synthetic": 1, "n_incremental": 3, "n_absolute": 3}


def small(tmp_path, **over):
    return load_dataset({**SMALL, "cache_dir": str(tmp_path), **over})


@pytest.mark.parametrize("noise, bound", [(0.0, 1.0), (1.0, 2.0)])
def test_ground_truth_is_exact(tmp_path, noise, bound):
    dataset = small(tmp_path, textures=["concrete"], n_incremental=4, sensor_noise=noise)
    judged = 0
    for pair in dataset.pairs("incremental"):
        ref, test = pair.reference.load(), pair.test.load()
        exact, n = fx.transfer_error(ref, test, pair.H)
        if n < 500:  # an almost non-overlapping pair: too few pixels to judge
            continue
        judged += 1
        shifted, _ = fx.transfer_error(ref, test, pair.H @ fx.SHIFT_2PX)
        assert exact < bound and shifted > 3 * exact, (pair.id, exact, shifted)
    assert judged >= 2


def test_same_seed_same_bytes_other_seed_other_images(tmp_path):
    a, b = small(tmp_path / "a"), small(tmp_path / "b")
    c = small(tmp_path / "c", seed=1)
    every = lambda d: [s for s in d.images("synthetic")] + [p.test for p in d.pairs("absolute")]  # noqa: E731
    first = [s.load().tobytes() for s in every(a)]
    assert first == [s.load().tobytes() for s in every(b)]
    assert first != [s.load().tobytes() for s in every(c)]
    assert all(np.array_equal(p.H, q.H) for p, q in zip(a.pairs("incremental"), b.pairs("incremental")))
    assert a.fingerprint() == b.fingerprint() != c.fingerprint()


def test_second_load_reads_the_cache(tmp_path, monkeypatch):
    first = small(tmp_path)
    index = next(tmp_path.rglob("index.json"))
    monkeypatch.setattr(synthetic, "render", lambda *a: pytest.fail("rendered twice"))
    again = small(tmp_path)
    assert len(again.pairs("absolute")) == 3 * 2 and again.fingerprint() == first.fingerprint()
    assert synthetic.generation_seconds(again, tmp_path) > 0
    assert [p.name for p in index.parent.parent.iterdir()] == [index.parent.name]  # no staging folder left


def test_a_process_running_numpys_avx512_loops_renders_another_data_set(tmp_path, monkeypatch):
    """NumPy imported before gtsweep on an AVX-512 machine renders some views to other bytes: its data set is
    cached and hashed apart, and the pinned one keeps its fingerprint."""
    pinned = small(tmp_path)
    monkeypatch.setattr(synthetic, "numpy_dispatch_pinned", lambda: False)
    unpinned = small(tmp_path)
    assert unpinned.fingerprint() != pinned.fingerprint()
    assert len({p.name for p in (tmp_path / "datasets").iterdir()}) == 2


def test_pair_statistics_follow_the_survey(tmp_path):
    dataset = small(tmp_path, textures=["wood"], n_incremental=40, n_absolute=40, n_synthetic=0)
    stats = stats_command.pair_statistics(dataset)
    inc, ab = stats["incremental"], stats["absolute"]
    assert abs(inc["overlap_mean"] - 0.227) < 0.02 and inc["overlap_min"] < 0.03
    assert abs(inc["rotation_mean"] - 3.0) < 0.5
    assert abs(ab["overlap_mean"] - 0.437) < 0.03 and abs(ab["rotation_mean"] - 120) < 5
    assert "0.227" in stats_command.format_statistics("synthetic", stats)


def test_views_stay_inside_their_floor_band(tmp_path):
    options = synthetic.check(synthetic.opts.read({**SMALL, "n_synthetic": 5}, synthetic.DEFAULTS, "synthetic"))
    side = synthetic.floor_side("concrete", options)
    plan = layout.plan_floor(side, options["view_size"], options["scale_jitter"])
    views = synthetic.plan_texture("concrete", options, plan)
    shape = (120, 160)
    for view in views:
        corners = geometry.footprint(view["pose"], shape)
        assert corners.min() >= 0 and corners.max() <= side - 1, view["id"]
    optimisation = [v for v in views if v["split"] == "optimisation"]
    others = [v for v in views if v["split"] != "optimisation"]
    assert plan.optimisation_box != plan.main_box
    assert all(overlap(o["pose"], v["pose"], shape) == 0 for o in optimisation for v in others)


def test_pair_layout_hits_its_targets():
    rng = np.random.default_rng(3)
    law = synthetic.PAIR_LAWS["incremental"]
    plan = layout.plan_floor(2560, (640, 480), 0.02)
    for reference, test, target in layout.pair_views(rng, 20, plan, (640, 480), 0.02, law):
        assert overlap(reference, test, (480, 640)) == pytest.approx(target, abs=1e-4)
        assert rotation_deg(reference, test) <= law["rotation_max"] + 1e-9
    u = layout.stratified(rng, 1024)
    assert np.all(np.sort(u) // (1 / 1024) == np.arange(1024))  # one draw per stratum at a power of two
    assert np.array_equal(layout.stratified(np.random.default_rng(5), 6),
                          layout.stratified(np.random.default_rng(5), 12)[:6])  # a prefix of a larger count
    assert layout.rotation_targets(rng, 2000, synthetic.PAIR_LAWS["absolute"]).__abs__().mean() == \
        pytest.approx(120, abs=1)
    with pytest.raises(BadInput, match="too small"):
        layout.plan_floor(500, (640, 480), 0.02)


def test_survey_view_size_gets_a_floor_large_enough():
    options = synthetic.check(synthetic.opts.read({"view_size": [1288, 964]}, synthetic.DEFAULTS, "synthetic"))
    for texture in ("wood", "gravel"):
        side = synthetic.floor_side(texture, options)
        layout.plan_floor(side, (1288, 964), 0.02)  # raises if a pair would not fit


def test_absolute_test_images_are_relit():
    rng = np.random.default_rng(0)
    params = photometric.draw(rng, synthetic.DEFAULTS["photometric"])
    assert set(params) == set(photometric.PARAMETERS)
    radiance = np.full((60, 80), 128.0, np.float32)
    plain = photometric.capture(radiance, np.random.default_rng(1), 0.0)
    relit = photometric.capture(radiance, np.random.default_rng(1), 0.0, {**params, "noise": 0.0, "blur": 0.0})
    assert np.all(plain == 128)
    assert relit[30, 40] != 128 and relit[0, 0] < relit[30, 40]  # other exposure, darker corners (vignetting)


def test_wood_has_the_weakest_texture():
    detector = cv2.FastFeatureDetector_create()
    counts = {}
    for kind in floors.PROCEDURAL:
        floor = floors.make_floor(kind, np.random.default_rng(0), (480, 640), floors.MICROGPS_PX_PER_MM)
        assert floor.dtype == np.float32 and 0 <= floor.min() and floor.max() <= 255 and floor.std() > 8
        counts[kind] = len(detector.detect(np.rint(floor).astype(np.uint8), None))
    assert min(counts, key=counts.get) == "wood" and counts["wood"] > 100, counts
    assert counts["fine_asphalt"] > counts["concrete"], counts


def test_bad_options(tmp_path):
    with pytest.raises(UnknownMethod, match="marble"):
        small(tmp_path, textures=["marble"])
    with pytest.raises(BadInput, match="overlap_mena"):
        small(tmp_path, incremental={"overlap_mena": 0.3})
    with pytest.raises(BadInput, match="view_size"):
        small(tmp_path, view_size=[160])
    with pytest.raises(BadInput, match="no parameter 'n_pairs'; its parameters: .*view_size"):
        small(tmp_path, n_pairs=3)


def test_the_defaults_are_written_once_in_the_yaml():
    """The synthetic data set's defaults are its YAML's values (the code reads them); a default data set's
    fingerprint, and so its rendered cache, stays as it was."""
    conf = yaml.safe_load((CONF_DIR / "dataset" / "synthetic.yaml").read_text())
    assert conf == {"loader": "synthetic", **synthetic.DEFAULTS}
    assert synthetic.PAIR_LAWS["absolute"] is synthetic.DEFAULTS["absolute"]
    assert set(synthetic.DEFAULTS["photometric"]) == set(photometric.PARAMETERS)
    fingerprints = [synthetic.fingerprint_of(synthetic.GENERATOR_VERSION, synthetic._content_options(
        synthetic.check(synthetic.opts.read(cfg, synthetic.DEFAULTS, "synthetic"))))
        for cfg in ({}, {"textures": ["tiles"], "view_size": [160, 120]})]
    assert fingerprints == ["47746f8e4d9c3386", "73743472f6ff458d"]


def test_stats_command(tmp_path, capsys):
    overrides = [f"dataset.cache_dir={tmp_path}", "dataset.textures=[tiles]", "dataset.view_size=[160,120]",
                 "dataset.n_incremental=4", "dataset.n_absolute=4"]
    assert stats_command.main(overrides) == 0
    out = capsys.readouterr().out
    assert "incremental" in out and "(0.437)" in out
    assert stats_command.main(["dataset=microgps", f"dataset.root={tmp_path}/missing"]) == 2
    err = capsys.readouterr().err
    assert "does not exist" in err and len(err.strip().splitlines()) == 1
    assert math.isfinite(float(out.split()[out.split().index("incremental") + 2]))
