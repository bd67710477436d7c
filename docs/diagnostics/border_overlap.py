"""How much of each incremental pair a detector with a border can see: ``python docs/diagnostics/border_overlap.py``.

A detector that finds nothing within ``b`` pixels of the image edge (CenSurE: about 1.5 x maxSize, 69 px at
maxSize 45) can only produce correspondences where a point lies at least ``b`` px inside both views. Incremental
pairs overlap in a strip along one edge, so their common area shrinks fast with ``b``. Prints, per border, the mean
common-area share of the incremental pairs of `make reproduce` and the share of pairs left with none or
almost none.
Options: ``--size 1288x964`` (view size), ``--borders 0 33 69``.
"""
import argparse

import numpy as np

from gtsweep.cli.overrides import compose_config
from gtsweep.datasets import load_dataset
from gtsweep.reproduction.command import SIZES


def common_area(H: np.ndarray, width: int, height: int, border: int, step: int = 2) -> float:
    """Share of the test view inside its border whose image under ``H`` lies inside the reference's border."""
    ys, xs = np.mgrid[0:height:step, 0:width:step]
    points = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    mapped = H @ points
    x, y = mapped[0] / mapped[2], mapped[1] / mapped[2]

    def inside(u, v):
        return (u >= border) & (u < width - border) & (v >= border) & (v < height - border)

    return float((inside(points[0], points[1]) & inside(x, y)).mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--borders", type=int, nargs="*", default=[0, 33, 69])
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    cfg = compose_config([*SIZES["hour"], f"dataset.view_size=[{width},{height}]"])  # make reproduce's pairs
    pairs = load_dataset(cfg.dataset).pairs("incremental")
    print(f"{len(pairs)} incremental pairs, {width}x{height} views")
    for border in args.borders:
        shares = np.array([common_area(p.H, width, height, border) for p in pairs])
        print(f"  border {border:3d} px: mean common area {shares.mean():.3f}, "
              f"pairs with none {(shares == 0).mean():.2f}, with < 1 % {(shares < 0.01).mean():.2f}")


if __name__ == "__main__":
    main()
