"""Cell hashes and reuse keys stay what they were: a finished cell of an earlier run (the committed reproduction
state, a user's results and caches) is kept only while its hash is unchanged, and its rows are reused only under
an unchanged reuse key. The strings below were computed by the code before the experiment kinds moved into their
own packages (gtsweep/experiments/<kind>/)."""
from __future__ import annotations

import pytest

from gtsweep.cli.overrides import compose_config
from gtsweep.core.config import config_hash
from gtsweep.experiments.kinds import EXPERIMENTS
from gtsweep.orchestration.view_reuse import reuse_key

FINGERPRINT, SEED = "fingerprint-pinned", 0
#: Library versions as a reuse key records them, fixed here (the real ones differ between machines).
VERSIONS = {"opencv": "pinned", "numpy": "pinned"}
CONFIGS = {
    "table3": ["sweeps=table3_detectors"],
    "table6": ["sweeps=table6_pairings"],
    "variants": ["experiment=pose", "detector=[sift]", "descriptor=[sift,orb]", "matcher=[bf_ratio,flann]",
                 "estimator=[ransac,magsac]", "transform=[rotation,incremental]"],
    "matching": ["experiment=matching", "detector=[orb]", "descriptor=[orb,brief]", "matcher=[bf_ratio,mutual_nn]",
                 "transform=[noise]"],
    "localization": ["experiment=localization", "detector=[sift,akaze]", "descriptor=[sift,akaze]",
                     "matcher=[bf_ratio,flann]", "estimator=[ransac,magsac]"],
}
#: name: (cells, hash of every cell's key and hash, [(key, cell hash, reuse key) of the first, middle, last cell])
PINNED = {
    "table3": (104, "f9d23579d87d2bfa", [
        ("agast__anms__-__gamma", "e7f22403160b63e0", "417bdf1e8795d2a5"),
        ("agast__anms__-__rotation", "ff5f41361b1ee8dc", "c54a021b46115a42"),
        ("xfeat__nms__-__translation", "87adad38382005da", "b80776997ca367d1"),
    ]),
    "table6": (36, "5bcc7ec715a4be3b", [
        ("sift__nms__sift__gamma", "ec88e93bc5316de0", "c7ce7bc17b1ffd09"),
        ("sift__nms__sift__rotation", "fd59a4a3ae838a43", "50e7fc724e64bb0a"),
        ("censure__nms__brief__translation", "499a1cdff4de0ccc", "58b9567b7cb0080d"),
    ]),
    "variants": (16, "277343e6c52f44f0", [
        ("sift__nms__orb__incremental__magsac", "327669289293684e", "1864b0adc94a6169"),
        ("sift__nms__orb__rotation__magsac", "d1bbc1f10e3e763b", "bdc1a4d56bc4f6c7"),
        ("sift__nms__sift__rotation__flann", "233f9d95c7c04310", "49cde1ed90cd9fdb"),
    ]),
    "matching": (4, "a5fbf6956f91a2db", [
        ("orb__nms__brief__noise", "ca15d226fd0163ca", "22e6ee90e155d4c8"),
        ("orb__nms__orb__noise", "b6995fbe45bdbf49", "4117e96b86f10dd7"),
        ("orb__nms__orb__noise__mutual_nn", "7e075ef6f59a55d6", "f3eb70508fde716b"),
    ]),
    "localization": (16, "9e9a9c0fb9f1dbe0", [
        ("akaze__nms__akaze__bf_ratio__magsac", "ac722deeb720ca2d", "ed6edaff3c558b32"),
        ("sift__nms__akaze__bf_ratio__magsac", "54ae85b19b46428a", "037a311a9a740ef3"),
        ("sift__nms__sift__flann__ransac", "595a50979187c53a", "7b836a09509ac908"),
    ]),
}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_cell_hashes_and_reuse_keys_are_unchanged(name):
    cfg = compose_config(CONFIGS[name])
    grid = EXPERIMENTS.get(cfg.experiment.name).cells.build_grid(cfg)
    cells = grid.cells
    count, every, picked = PINNED[name]
    assert len(cells) == count
    assert config_hash([[c.key, grid.cell_hash(c, FINGERPRINT, SEED)] for c in cells]) == every
    found = [(c.key, grid.cell_hash(c, FINGERPRINT, SEED), reuse_key(grid, c, SEED, VERSIONS))
             for c in (cells[0], cells[len(cells) // 2], cells[-1])]
    assert found == picked
