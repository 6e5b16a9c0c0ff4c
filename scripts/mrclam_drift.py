"""How long an MRCLAM robot's odometry keeps a map consistent: the drift that sets kappa.

For raw (dead-reckoned) and VIO-like odometry, prints the root mean square error with which the
odometry places, in the robot's current frame, a landmark it sighted kappa seconds earlier
(`mrclam.map_drift`: at the median sighting range, over every robot and time; vio for each
seed), and the longest kappa of the grid at which it stays within half of CLIPPER's epsilon for
every seed: two landmarks of one map then keep their distance within epsilon, which the
consistency graph needs.

    python scripts/mrclam_drift.py --data ../shared/data/mrclam/MRCLAM_Dataset6 [--seeds 3]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from tcaff_gtsam.eval.config import load_mrclam
from tcaff_gtsam.eval.datasets import mrclam

from tcaff_gtsam.params import ClipperParams


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="an MRCLAM data set folder")
    parser.add_argument("--seeds", type=int, default=3, help="seeds of the VIO-like odometry")
    parser.add_argument("--kappas", type=float, nargs="+",
                        default=[5, 10, 20, 30, 60, 90, 120, 150, 180, 240, 300],
                        help="spans to evaluate, s")
    args = parser.parse_args()
    config = load_mrclam("default")
    data = mrclam.read_dataset(args.data)
    bound = ClipperParams().epsilon / 2
    kappas = np.array(sorted(args.kappas))
    rows = [("raw", mrclam.map_drift(data, "raw", None, kappas,
                                     config.vio.heading_rw_deg_per_sqrt_min,
                                     config.vio.scale_std))]
    rows += [(f"vio seed {s}", mrclam.map_drift(data, "vio", s, kappas,
                                                config.vio.heading_rw_deg_per_sqrt_min,
                                                config.vio.scale_std))
             for s in range(args.seeds)]
    print(f"{args.data.name}: RMS misplacement [m] of a landmark sighted kappa s ago; "
          f"bound epsilon / 2 = {bound:.3f} m")
    print(f"{'odometry':12} " + " ".join(f"{k:>7g}" for k in kappas))
    for name, drift in rows:
        print(f"{name:12} " + " ".join(f"{d:7.3f}" for d in drift))
    for odometry in ("raw", "vio"):
        worst = np.nanmax([d for name, d in rows if name.startswith(odometry)], axis=0)
        within = kappas[worst <= bound]
        longest = f"{within.max():g} s" if within.size else "none of the grid"
        print(f"{odometry}: longest kappa within the bound: {longest} "
              f"(configured: {config.kappa_of(odometry):g} s)")


if __name__ == "__main__":
    main()
