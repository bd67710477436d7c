"""A method parameter given on the command line is merged onto the method's defaults in one place: the grid's
:func:`~gtsweep.orchestration.grid.resolve_group`. The command line checks it against the defaults without merging;
the pre-flight build and the task receive the full parameters (merging those onto the defaults changes nothing)."""
from __future__ import annotations

import numpy as np

from gtsweep.cli import overrides as cli
from gtsweep.core.registry import Method
from gtsweep.orchestration.grid import build_grid
from gtsweep.stages.detect import detect_timed


def test_a_command_line_parameter_is_merged_onto_its_defaults_once(monkeypatch):
    merges, calls = [], []
    original = Method.params

    def counting(self, overrides=None):
        if self.family == "detector" and self.name == "orb":
            calls.append(dict(overrides or {}))
            if overrides and set(overrides) != set(self.defaults):  # some defaults filled in: a real merge
                merges.append(dict(overrides))
        return original(self, overrides)

    monkeypatch.setattr(Method, "params", counting)
    args = ["detector=[orb]", "descriptor=[orb]", "detector.orb.params.nfeatures=500"]
    cli.prepare(args)  # the command line's checks
    assert calls == []  # checked against the defaults, never merged
    grid = build_grid(cli.compose_config(args))
    params = grid.detectors["orb"]["params"]
    assert params["nfeatures"] == 500 and len(params) > 1  # the full parameters travel on
    image = np.random.default_rng(0).integers(0, 255, (240, 320), dtype=np.uint8)
    detect_timed(image, "orb", None, **params)  # what a detection task does with the grid's parameters
    assert merges == [{"nfeatures": 500}]
