"""One registry shape for every method family: strict parameter merge, one lookup, a pre-flight build."""
import subprocess
import sys

import numpy as np
import pytest

from gtsweep.cli import overrides as cli
from gtsweep.core.errors import BadInput, GtsweepError, NotApplicable, UnknownMethod
from gtsweep.core.registry import Method, Registry, lazy_factory, reason_line
from gtsweep.datasets import DATASETS, load_dataset
from gtsweep.evaluation.transforms import TRANSFORMS, synthesize
from gtsweep.experiments.pairs.grid import build_grid
from gtsweep.orchestration.grid import resolve_group
from gtsweep.stages.describe import DESCRIPTORS, DescriptorSpec, describe
from gtsweep.stages.detect import DETECTORS, DetectorSpec, detect, probe_image
from gtsweep.stages.select import SELECTORS, select
from sweep_helpers import checked_jobs

FAMILIES = {"detector": (DETECTORS, DetectorSpec), "descriptor": (DESCRIPTORS, DescriptorSpec),
            "selector": (SELECTORS, Method), "transform": (TRANSFORMS, Method), "dataset loader": (DATASETS, Method)}


def _sift():
    return DETECTORS.get("sift")


def test_every_family_is_a_registry_of_methods():
    for family, (registry, kind) in FAMILIES.items():
        assert isinstance(registry, Registry) and registry.family == family and len(registry) > 0
        for name, method in registry.items():
            assert isinstance(method, kind) and method.family == family and method.name == name, name
            assert isinstance(method.defaults, dict) and method.label


def test_params_merge_strictly_onto_the_defaults():
    sift = _sift()
    assert sift.params() == dict(sift.defaults)
    assert sift.params({"contrastThreshold": 0.02})["contrastThreshold"] == 0.02
    assert sift.params({"edgeThreshold": 12})["edgeThreshold"] == 12  # an int is a fine float
    with pytest.raises(BadInput, match="detector 'sift' has no parameter 'contrastThreshol'; its parameters: "
                                       "contrastThreshold, edgeThreshold, nOctaveLayers, nfeatures, sigma"):
        sift.params({"contrastThreshol": 0.02})
    with pytest.raises(BadInput, match=r"nOctaveLayers=2\.5 should be int like its default 3"):
        sift.params({"nOctaveLayers": 2.5})
    with pytest.raises(BadInput, match="should be bool"):
        DETECTORS.get("fast").params({"nonmaxSuppression": 1})


def test_unknown_parameter_names_the_valid_ones_in_every_family():
    image = np.zeros((32, 32), np.uint8)
    calls = [(lambda: detect(image, "orb", nfeaturez=10), "its parameters: edgeThreshold, fastThreshold"),
             (lambda: describe(image, np.zeros((0, 7)), "brief", "fast", byts=16), "its parameters: bytes"),
             (lambda: select(np.zeros((0, 7)), "nms", (10, 10), rows=3), "selector 'nms' has no parameter 'rows'; "
                                                                         "its parameters: n"),
             (lambda: synthesize("gamma", image, 2.0, border=3), "transform 'gamma' has no parameter 'border'"),
             (lambda: load_dataset({"loader": "folder", "roots": "x"}), "its parameters: .*root")]
    for call, message in calls:
        with pytest.raises(BadInput, match=message) as info:
            call()
        assert "\n" not in str(info.value)


def test_unknown_name_lists_the_choices():
    for family, (registry, _) in FAMILIES.items():
        with pytest.raises(UnknownMethod, match=f"unknown {family} 'nope'; valid choices: ") as info:
            registry.get("nope")
        assert set(info.value.choices) == set(registry)
    assert DETECTORS.get("nope", None) is None and DETECTORS["sift"] is _sift()


def test_build_reports_a_missing_method_and_a_rejected_parameter_in_one_line():
    missing = Method("detector", "ghost", "Ghost", lazy_factory("gtsweep.no_such_module", "Ghost_create"))
    with pytest.raises(GtsweepError, match="detector 'ghost' is not available"):
        missing.build()
    with pytest.raises(BadInput, match=r"descriptor 'brief' rejects bytes=7: \(-5:Bad argument\) bytes must be 16, "
                                       r"32, or 64") as info:
        DESCRIPTORS.get("brief").build({"bytes": 7})
    assert "\n" not in str(info.value) and "OpenCV(" not in str(info.value)


def test_reason_line_is_the_last_line_without_opencvs_source_location():
    error = Exception("OpenCV(5.0.0) :-1: error: (-5:Bad argument)\n"
                      "OpenCV(5.0.0) /io/src/brief.cpp:196: error: (-5:Bad argument) bytes must be 16")
    assert reason_line(error) == "(-5:Bad argument) bytes must be 16"
    assert reason_line(ValueError()) == "ValueError"


def _cfg(detector_params=None, descriptor_node=None):
    return {"detector": {"sift": {"params": detector_params or {}}, "fast": {"params": {}}},
            "selector": {"nms": {"params": {}}},
            "descriptor": {"brief": descriptor_node or {"params": {}}},
            "transform": {"rotation": {"kind": "synthetic", "strengths": [0, 90]}},
            "experiment": {"name": "matching"}}


def test_grid_sees_the_full_effective_parameters():
    grid = build_grid(_cfg({"contrastThreshold": 0.02}))
    assert grid.detectors["sift"]["params"] == {**_sift().defaults, "contrastThreshold": 0.02}
    assert grid.detectors["fast"]["params"] == DETECTORS.get("fast").defaults
    assert grid.selectors["nms"]["params"] == {"n": 1000}
    assert grid.transforms["rotation"]["params"] == {"border": 3}
    assert resolve_group(_cfg(), "descriptor") == {"brief": {"params": {"bytes": 32, "use_orientation": True}}}


@pytest.mark.parametrize("cfg, message", [
    (_cfg({"nOctaveLayers": 0}), r"detector 'sift' rejects nOctaveLayers=0: \(-215:Assertion failed\)"),
    (_cfg(descriptor_node={"params": {}, "per_detector": {"fast": {"bytes": 7}}}),
     r"descriptor 'brief' rejects bytes=7: .*bytes must be 16, 32, or 64"),
    (_cfg(descriptor_node={"params": {}, "per_detector": {"fast": {"byts": 16}}}),
     "descriptor 'brief' has no parameter 'byts'"),
    (_cfg(descriptor_node={"params": {}, "per_detector": {"fsat": {"bytes": 16}}}), "unknown detector 'fsat'"),
    ({**_cfg(), "selector": {"nms": {"params": {"n": 0}}}}, "selector 'nms' rejects n=0: n must be a positive"),
])
def test_preflight_stops_a_rejected_parameter_in_one_line(cfg, message):
    with pytest.raises(GtsweepError, match=message) as info:
        build_grid(cfg)
    assert "\n" not in str(info.value)


def test_an_opencv_failure_is_an_error_not_na():
    image = probe_image()
    sift = detect(image, "sift")
    with pytest.raises(GtsweepError) as info:  # the survey's NA rule, bypassed: OpenCV's own failure
        describe(image, sift, "akaze", "sift")
    assert not isinstance(info.value, NotApplicable) and "class_id" in str(info.value)
    with pytest.raises(GtsweepError) as info:
        detect(image, "sift", nOctaveLayers=0)
    assert not isinstance(info.value, NotApplicable) and "detector 'sift' failed: (-215" in str(info.value)


def test_describe_does_not_import_detect():
    code = "import sys, gtsweep.stages.describe; print('gtsweep.stages.detect' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"


def test_cli_passes_method_parameters_to_hydra_as_they_are(tmp_path, monkeypatch):
    """A method's YAML composes onto its schema (its defaults in code): every parameter is in the config, so an
    override needs no force-add, and Hydra refuses an unselected method's."""
    args = ["detector=[sift]", "detector.sift.params.contrastThreshold=0.02", "seed=1"]
    cfg = cli.compose_config(args)
    assert build_grid(cfg).detectors["sift"]["params"] == {**_sift().defaults, "contrastThreshold": 0.02}
    assert cli.compose_config(["sweeps=smoke", "detector.sift.params.sigma=1.5"]).detector.sift.params.sigma == 1.5
    with pytest.raises(SystemExit) as exit_info:  # the sweeper checks every job before any runs
        checked_jobs(["detector=[sift],[sift,orb]", "detector.orb.params.nfeatures=5"], tmp_path, monkeypatch)
    assert exit_info.value.code == 2
