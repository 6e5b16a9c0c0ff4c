"""Time the mapping front end per RGB-D frame, split into its stages.

Rings of boxes and bins (cylinders) are rendered at 640 x 480 from a robot driving towards them;
each frame goes through `RgbdFrontEnd` (depth segmenter, mask filter, Open3D lifting, tracker).
Prints the median and 90th percentile of each stage, and the number of masks lifted per frame.
Then the same for the real frames in `--data` (TUM, NYU, Redwood; skipped when absent), each
processed `--repeats` times, and for the hand-held 7-Scenes sequence in `--sequence` (640 x 480
Kinect frames with camera poses; skipped when absent), every frame once, in order, as a moving
camera gives them (the pose of each frame tells the segmenter where gravity is).

Targets per 640 x 480 frame: the whole front end <= 30 ms, lifting and tracking included;
segmentation + mask filter <= 12 ms; lifting + tracking <= 15 ms with about 20 masks (the
paper's whole mapping step took 13.5 ms). The machine's load average is printed with each
table: the times are wall times, and other work on the machine lengthens them.

    python scripts/bench_mapping.py [--frames 60] [--rings 7] [--width 640 --height 480]
                                    [--data ../shared/data/rgbd] [--repeats 15]
                                    [--sequence ../shared/data/rgbd/7scenes_redkitchen]
                                    [--sequence-frames 0]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import cv2
import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from tcaff_gtsam.eval.datasets.rgbd_frames import load_folder
from tcaff_gtsam.eval.sim.render import RgbdScene, render
from tcaff_gtsam.eval.sim.world import World
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera
from tcaff_gtsam.mapping.frontend import RgbdFrontEnd

from tcaff_gtsam.geometry import se3_from_xyz_yaw

STAGES = ("register", "segment", "filter", "lift", "track")
TARGETS = {"segment + filter": "<= 12 ms", "lift + track": "<= 15 ms", "total": "<= 30 ms"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60, help="frames to time")
    parser.add_argument("--rings", type=int, default=7, help="rings of 7 objects ahead")
    parser.add_argument("--width", type=int, default=640, help="image width, pixels")
    parser.add_argument("--height", type=int, default=480, help="image height, pixels")
    parser.add_argument("--noise", type=float, default=0.0025,
                        help="depth noise std at 1 m (grows with range squared)")
    parser.add_argument("--data", type=Path, default=Path("../shared/data/rgbd"),
                        help="folder of real frames (TUM, NYU, Redwood)")
    parser.add_argument("--repeats", type=int, default=15, help="runs of each real frame")
    parser.add_argument("--sequence", type=Path,
                        default=Path("../shared/data/rgbd/7scenes_redkitchen"),
                        help="folder of a 7-Scenes sequence (frame-XXXXXX.color.jpg, "
                             ".depth.png, .pose.txt, camera-intrinsics.txt, "
                             "gravity-direction.txt)")
    parser.add_argument("--sequence-frames", type=int, default=0,
                        help="frames of the sequence to time (0: all)")
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    # Rings of objects ahead of the robot, staggered so that each row shows between the
    # objects of the row in front: about 20 are in view at once.
    xy = []
    for ring, radius in enumerate(np.linspace(2.0, 6.0, args.rings)):
        bearings = np.linspace(-0.6, 0.6, 7) + (0.1 if ring % 2 else 0.0)
        xy += [radius * np.array([np.cos(b), np.sin(b)]) for b in bearings]
    xy = np.array(xy)
    n = len(xy)
    kinds = np.where(np.arange(n) % 3 == 0, "bin", "box")
    world = World(xy, rng.uniform(0.2, 0.35, n), rng.uniform(0.3, 0.8, n), kinds)
    scene = RgbdScene.from_world(world, yaws=rng.uniform(0, np.pi / 2, n))
    camera = PinholeCamera.from_fov(args.width, args.height, 87.0)
    front_end = RgbdFrontEnd(camera, T_body_camera(0.6, 5.0), depth_scale=1.0)

    frames = []
    for f in range(args.frames + 5):
        heading = 0.1 * np.sin(2 * np.pi * f / args.frames)  # sway the view left and right
        T_world_body = se3_from_xyz_yaw(-0.5 + 0.01 * f, 0.0, 0.0, heading)
        frame = render(scene, T_world_body @ front_end.T_body_camera, camera, args.noise, rng)
        result = front_end.process(0.1 * f, frame.rgb, frame.depth, T_world_body)
        if f >= 5:  # after warm-up (first calls initialise Open3D and OpenCV)
            frames.append(result)

    stage_table(f"Mapping front end per {args.width} x {args.height} frame", frames)
    print(f"{args.frames} rendered frames; {load()}")
    print(f"objects in the map: {len(front_end.object_map())} of {len(world)} in the room")
    if args.data.is_dir():
        bench_real(args.data, args.repeats)
    if args.sequence.is_dir():
        bench_sequence(args.sequence, args.sequence_frames)


def load() -> str:
    """The machine's load averages over 1, 5 and 15 minutes, as words."""
    return "load average " + ", ".join(f"{v:.1f}" for v in os.getloadavg())


def stage_table(title: str, results: list) -> None:
    """Median and p90 of each stage of the front end's `FrameResult`s, of segment + filter,
    lift + track and the total, against the targets; then the masks per frame."""
    ms = {s: 1e3 * np.array([r.seconds[s] for r in results]) for s in STAGES}
    ms["segment + filter"] = ms["segment"] + ms["filter"]
    ms["lift + track"] = ms["lift"] + ms["track"]
    ms["total"] = sum(ms[s] for s in STAGES)
    table = Table(title=title)
    table.add_column("stage")
    table.add_column(escape("median [ms]"), justify="right")  # [ms] is not rich markup
    table.add_column(escape("p90 [ms]"), justify="right")
    table.add_column("target", justify="right")
    for name, values in ms.items():
        table.add_row(name, f"{np.median(values):.2f}", f"{np.percentile(values, 90):.2f}",
                      TARGETS.get(name, ""))
    Console(width=120).print(table)
    print(f"masks per frame (median): {np.median([r.n_masks for r in results]):.0f} from the "
          f"segmenter, {np.median([len(r.observations) for r in results]):.0f} lifted")


def bench_real(folder: Path, repeats: int) -> None:
    """Median and p90 of segmentation and lift + track on each real frame."""
    table = Table(title=f"Real frames in {folder} ({repeats} runs each, after one warm-up; "
                        f"{load()})")
    for name in ("frame", "size", "masks", "lifted", "segment median [ms]", "segment p90 [ms]",
                 "lift + track median [ms]", "lift + track p90 [ms]"):
        table.add_column(escape(name), justify="left" if name == "frame" else "right")
    for name, f in load_folder(folder).items():
        front_end = RgbdFrontEnd(f.camera, f.T_body_camera, depth_scale=1.0)
        runs = [front_end.process(0.1 * i, f.rgb, f.depth, np.eye(4))
                for i in range(repeats + 1)][1:]
        seg = 1e3 * np.array([r.seconds["segment"] for r in runs])
        lt = 1e3 * np.array([r.seconds["lift"] + r.seconds["track"] for r in runs])
        table.add_row(name, f"{f.camera.width} x {f.camera.height}", str(runs[0].n_masks),
                      str(len(runs[0].observations)), f"{np.median(seg):.1f}",
                      f"{np.percentile(seg, 90):.1f}", f"{np.median(lt):.1f}",
                      f"{np.percentile(lt, 90):.1f}")
    Console(width=160).print(table)
    print("targets: segment + filter " + TARGETS["segment + filter"] + " (the mask filter "
          "adds 2-3 ms to the segmentation above), lift + track " + TARGETS["lift + track"])


def bench_sequence(folder: Path, limit: int) -> None:
    """The front end over a hand-held 7-Scenes sequence, every frame once in order.

    The poses are T_world_camera in a world that is not gravity aligned;
    gravity-direction.txt is gravity in that world. The front end is given the poses in a
    gravity-aligned world (z up) and the camera as its body, so that each frame's pose says
    which planes are level. Depth is 16-bit millimetres (65535: no return). The first frame
    is a warm-up (the compiled kernels are loaded) and not timed.
    """
    paths = sorted(folder.glob("frame-*.depth.png"))
    if limit > 0:
        paths = paths[:limit + 1]
    if not paths:
        print(f"no frame-*.depth.png in {folder}")
        return
    g = np.loadtxt(folder / "gravity-direction.txt")
    z = -g / np.linalg.norm(g)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    T_level_world = np.eye(4)
    T_level_world[:3, :3] = np.vstack([x, np.cross(z, x), z])  # rows: the level axes
    first = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED)
    camera = PinholeCamera.from_K(np.loadtxt(folder / "camera-intrinsics.txt"),
                                  width=first.shape[1], height=first.shape[0])
    front_end = RgbdFrontEnd(camera, np.eye(4), depth_scale=1000.0)
    results = []
    for k, path in enumerate(paths):
        stem = str(path)[:-len(".depth.png")]
        rgb = cv2.imread(stem + ".color.jpg")[..., ::-1].copy()
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        depth[depth == 65535] = 0
        index = int(Path(stem).name.split("-")[1])
        T = T_level_world @ np.loadtxt(stem + ".pose.txt")
        result = front_end.process(index / 30.0, rgb, depth, T)  # 30 Hz recording
        if k > 0:
            results.append(result)
    stage_table(f"Front end per {camera.width} x {camera.height} frame of {folder.name}",
                results)
    print(f"{len(results)} hand-held frames, each once, in order; {load()}")
    print(f"objects in the map: {len(front_end.object_map())}")


if __name__ == "__main__":
    main()
