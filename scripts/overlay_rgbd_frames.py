"""Overlay figures of the mapping front end on the real RGB-D frames.

Each frame of a folder laid out like `../shared/data/rgbd` (TUM, NYU, Redwood) goes through
`RgbdFrontEnd` with its defaults and the frame's camera attitude. One PNG per frame shows every
lifted mask tinted on the colour image, labelled with its track id and its size (width x height,
metres) and the height of its centroid above the floor; a table of the counts is printed.

    python scripts/overlay_rgbd_frames.py [--data ../shared/data/rgbd] [--out overlays]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
from rich.console import Console
from rich.table import Table
from tcaff_gtsam.eval.datasets.rgbd_frames import load_folder
from tcaff_gtsam.mapping.frontend import RgbdFrontEnd


def overlay(rgb: np.ndarray, masks: np.ndarray, labels: list[str]) -> np.ndarray:
    """(H, W, 3) uint8 BGR: `rgb` with each mask ((k, H, W) bool) tinted and labelled."""
    img = np.ascontiguousarray(rgb[..., ::-1])
    colours = np.random.default_rng(1).integers(60, 256, (len(masks), 3))
    for mask, colour in zip(masks, colours, strict=True):
        img[mask] = (img[mask] * 0.45 + colour * 0.55).astype(np.uint8)
    for mask, text in zip(masks, labels, strict=True):
        ys, xs = np.nonzero(mask)
        at = (max(int(xs.mean()) - 45, 0), int(ys.mean()))
        for colour, thick in (((0, 0, 0), 3), ((255, 255, 255), 1)):
            cv2.putText(img, text, at, cv2.FONT_HERSHEY_SIMPLEX, 0.42, colour, thick)
    return img


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data/rgbd"),
                        help="folder of the frames (default ../shared/data/rgbd)")
    parser.add_argument("--out", type=Path, default=Path("overlays"),
                        help="folder the PNGs are written to (created)")
    args = parser.parse_args()
    frames = load_folder(args.data)
    if not frames:
        print(f"error: no TUM, NYU or Redwood frames in {args.data}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    table = Table("frame", "masks", "lifted", "distinct ids", "objects (w x h m, centroid z m)")
    for name, f in frames.items():
        front = RgbdFrontEnd(f.camera, f.T_body_camera, depth_scale=1.0)
        r = front.process(0.0, f.rgb, f.depth, np.eye(4))
        o = r.observations
        labels = [f"#{t} {w:.2f}x{h:.2f} z{c[2]:.2f}"
                  for t, w, h, c in zip(r.track_ids, o.widths, o.heights, o.centroids,
                                        strict=True)]
        path = args.out / f"{name}.png"
        cv2.imwrite(str(path), overlay(f.rgb, r.masks, labels))
        table.add_row(name, str(r.n_masks), str(len(o)), str(np.unique(r.track_ids).size),
                      "; ".join(f"{w:.2f}x{h:.2f} ({c[2]:.2f})" for w, h, c in
                                zip(o.widths, o.heights, o.centroids, strict=True)))
    Console(width=200).print(table)
    print(f"overlays written to {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
