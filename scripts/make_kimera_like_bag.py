"""Write small ROS1 bags laid out like the Kimera-Multi data set, from the rendered RGB-D simulator.

The writer is `tcaff_gtsam.eval.sim.kimera_bags.write_sequence`; this is its command line:

    python scripts/make_kimera_like_bag.py --out data/kimera_like --seconds 30
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.progress import Progress, TaskID
from tcaff_gtsam.eval.sim import kimera_bags

from tcaff_gtsam.errors import ConfigError


def main() -> None:
    class Help(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
        pass

    parser = argparse.ArgumentParser(description=kimera_bags.__doc__, formatter_class=Help)
    add = parser.add_argument
    add("--out", type=Path, default=Path("kimera_like"), help="output folder")
    add("--robots", nargs="+", default=["acl_jackal2", "sparkal2"],
        help="robot names, one per robot of the scenario")
    add("--seconds", type=float, default=30.0, help="length of the sequence, s")
    add("--rate", type=float, default=10.0, help="colour and depth frame rate, Hz, dividing 50")
    add("--width", type=int, default=640, help="image width, pixels")
    add("--height", type=int, default=480, help="image height, pixels")
    add("--seed", type=int, default=0, help="random seed of world, paths, drift and noise")
    add("--scenario", default="indoor_rgbd", help="shipped scenario name or YAML path")
    add("--depth-noise", type=float, default=0.0025,
        help="depth std at 1 m range, m; grows with range squared")
    add("--camera-height", type=float, default=0.6, help="colour camera above the body, m")
    add("--camera-pitch", type=float, default=5.0, help="colour camera looking down, deg")
    add("--camera-forward", type=float, default=0.2, help="colour camera ahead of the body, m")
    args = parser.parse_args()
    with Progress() as bar:
        tasks: dict[str, TaskID] = {}

        def progress(robot: str, done: int, total: int) -> None:
            if robot not in tasks:
                tasks[robot] = bar.add_task(robot, total=total)
            bar.update(tasks[robot], completed=done)

        try:
            kimera_bags.write_sequence(args.out, args.robots, args.seconds, args.rate, args.width,
                           args.height, args.seed, args.scenario, args.depth_noise, progress,
                           camera_height=args.camera_height, camera_pitch_deg=args.camera_pitch,
                           camera_forward=args.camera_forward)
        except ConfigError as exc:
            parser.error(str(exc))
    print(f"wrote {', '.join(f'{r}.bag' for r in args.robots)} and GT CSVs to {args.out}")


if __name__ == "__main__":
    main()
