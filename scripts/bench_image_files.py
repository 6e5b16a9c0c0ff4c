"""Time the check that refuses a JPEG cut short (`image_files.jpeg_defect`, the marker walk to
the end-of-image marker) against the check it replaced (the file's last bytes must be that
marker), and what reading an image costs in all, on the shared RGB-D images.

Per set of files: the mean size, the old and the new check on the bytes in memory, OpenCV's
decode alone, and reading an image whole as `read_image` does (the file from the page cache,
the check, the decode) with the old check and with the new one; medians over `--repeat` passes
of the per-file means. PNG files get no JPEG check (both columns: the test of the first two
bytes). The last row re-encodes the 7-Scenes frames as progressive JPEGs with restart markers
(OpenCV, quality 95), in memory.

    python scripts/bench_image_files.py [--data ../shared/data/rgbd] [--repeat 15]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from tcaff_gtsam.eval.datasets.image_files import JPEG_START, jpeg_defect


def old_defect(data: bytes) -> str | None:
    """The check before the marker walk: a JPEG must end with its end-of-image marker, zero
    bytes of padding after it aside."""
    return None if data.rstrip(b"\x00").endswith(b"\xff\xd9") else "cut short"


def checked(data: bytes, check: Callable[[bytes], str | None]) -> None:
    if data.startswith(JPEG_START) and check(data) is not None:
        raise RuntimeError("a whole image refused")


def read_with(check: Callable[[bytes], str | None], path: Path) -> np.ndarray:
    """`read_image`'s steps with `check` in place of its own (the error paths left out)."""
    data = path.read_bytes()
    checked(data, check)
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)


def per_item_us(works: list[Callable[[object], object]], items: list, repeat: int
                ) -> list[float]:
    """Per work, the median over `repeat` passes of the mean time of `work(item)`, in
    microseconds; each pass runs every work in turn, so that a machine's changing load falls
    on all of them alike."""
    means: list[list[float]] = [[] for _ in works]
    for _ in range(repeat):
        for work, times in zip(works, means, strict=True):
            start = time.perf_counter()
            for item in items:
                work(item)
            times.append((time.perf_counter() - start) / len(items))
    return [1e6 * statistics.median(times) for times in means]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data/rgbd"))
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()
    kitchen, redwood = args.data / "7scenes_redkitchen", args.data / "redwood_livingroom"
    sets = [("7-Scenes colour JPEG", sorted(kitchen.glob("*.color.jpg"))),
            ("7-Scenes depth PNG", sorted(kitchen.glob("*.depth.png"))),
            ("Redwood colour JPEG", sorted((redwood / "color").glob("*.jpg"))),
            ("TUM colour PNG", [args.data / "TUM_color.png"]),
            ("TUM depth PNG", [args.data / "TUM_depth.png"])]
    print(f"{'files':<34}{'n':>5}{'kB':>7}{'old check':>11}{'new check':>11}{'decode':>9}"
          f"{'read before':>13}{'read after':>12}{'added':>8}")
    print(f"{'':<34}{'':>5}{'':>7}{'us':>11}{'us':>11}{'us':>9}{'us':>13}{'us':>12}{'':>8}")

    def row(name: str, blobs: list[bytes], paths: list[Path] | None) -> None:
        old, new = per_item_us([lambda d: checked(d, old_defect),
                                lambda d: checked(d, jpeg_defect)], blobs, args.repeat)
        arrays = [np.frombuffer(d, np.uint8) for d in blobs]
        decode, = per_item_us([lambda a: cv2.imdecode(a, cv2.IMREAD_UNCHANGED)], arrays,
                              args.repeat)
        if paths:
            before, after = per_item_us([lambda p: read_with(old_defect, p),
                                         lambda p: read_with(jpeg_defect, p)], paths,
                                        args.repeat)
            reads = f"{before:13.0f}{after:12.0f}{100 * (after - before) / before:+7.1f}%"
        else:
            reads = f"{'-':>13}{'-':>12}{'-':>8}"
        kb = np.mean([len(d) for d in blobs]) / 1000
        print(f"{name:<34}{len(blobs):5d}{kb:7.1f}{old:11.1f}{new:11.1f}{decode:9.0f}{reads}")

    for name, paths in sets:
        if not paths:
            print(f"{name:<34}    0 (no files under {args.data})")
            continue
        row(name, [p.read_bytes() for p in paths], paths)
    frames = [cv2.imread(str(p)) for p in sets[0][1]]
    if frames:
        params = [cv2.IMWRITE_JPEG_QUALITY, 95, cv2.IMWRITE_JPEG_PROGRESSIVE, 1,
                  cv2.IMWRITE_JPEG_RST_INTERVAL, 8]
        blobs = [cv2.imencode(".jpg", f, params)[1].tobytes() for f in frames]
        row("7-Scenes progressive, RST (memory)", blobs, None)


if __name__ == "__main__":
    main()
