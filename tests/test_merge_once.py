"""A method parameter given on the command line is merged onto the method's defaults in one place: Hydra's
composition, onto the method's schema in the ConfigStore (:mod:`gtsweep.orchestration.schemas`). The command line's
checks compose without gtsweep merging anything; the grid, the pre-flight build and the task receive the full
parameters (a strict :meth:`~gtsweep.core.registry.Method.params` of full parameters adds nothing), each checking them
once."""
from __future__ import annotations

import numpy as np
from omegaconf import OmegaConf

from gtsweep.cli import overrides as cli
from gtsweep.core.registry import Method
from gtsweep.experiments.pairs.grid import build_grid
from gtsweep.orchestration import schemas
from gtsweep.stages.detect import DETECTORS, detect_timed


def test_a_command_line_parameter_is_merged_onto_its_defaults_once(monkeypatch):
    merges, calls, stored = [], [], []
    original_params, original_schema = Method.params, schemas.method_schema

    def counting(self, overrides=None):
        if self.family == "detector" and self.name == "orb":
            calls.append(dict(overrides or {}))
            if overrides is not None and set(overrides) != set(self.defaults):  # defaults filled in: a merge
                merges.append(dict(overrides))
        return original_params(self, overrides)

    def schema(name, defaults):  # what Hydra composes onto: the code defaults, as they are
        stored.append(name)
        return original_schema(name, defaults)

    monkeypatch.setattr(Method, "params", counting)
    monkeypatch.setattr(schemas, "method_schema", schema)
    args = ["detector=[orb]", "descriptor=[orb]", "detector.orb.params.nfeatures=500"]
    cfg = cli.compose_config(args)  # the command line's checks: Hydra composes the job, gtsweep merges nothing
    assert calls == [] and "orb" in stored
    composed = OmegaConf.to_container(cfg.detector.orb.params)
    assert composed == {**DETECTORS.get("orb").defaults, "nfeatures": 500}  # merged by Hydra, in full
    grid = build_grid(cfg)
    params = grid.detectors["orb"]["params"]
    image = np.random.default_rng(0).integers(0, 255, (240, 320), dtype=np.uint8)
    detect_timed(image, "orb", None, **params)  # what a detection task does with the grid's parameters
    assert params == composed and merges == []  # nobody after Hydra merged defaults in again
    assert calls == [composed, composed]  # one strict check in the grid's pre-flight build, one in the task's
