"""Start-up time of the `tcaff` command and of the package imports, each in a fresh process.

Every case runs once unmeasured (disk caches, bytecode), then N times, each in a new
interpreter; the table gives median and minimum wall time, and the target where the project
sets one. Exits non-zero when a case fails to run (the others are still measured).

    python scripts/bench_startup.py [--repeat 7] [--importtime MODULE [--top 15]]

--importtime MODULE prints instead the slowest imports of `import MODULE` (python -X importtime:
cumulative and own milliseconds, nested imports indented).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

BIN = Path(sys.executable).parent
TCAFF = BIN / "tcaff"

# (label, argv, target seconds or None)
CASES: list[tuple[str, list[str], float | None]] = [
    ("tcaff --help", [str(TCAFF), "--help"], 0.8),
    ("import tcaff_gtsam", [sys.executable, "-c", "import tcaff_gtsam"], 0.5),
    ("import tcaff_gtsam.eval.cli", [sys.executable, "-c", "import tcaff_gtsam.eval.cli"], None),
    ("import tcaff_gtsam.mapping", [sys.executable, "-c", "import tcaff_gtsam.mapping"], None),
    ("import tcaff_gtsam.eval.sim.simulate",
     [sys.executable, "-c", "import tcaff_gtsam.eval.sim.simulate"], None),
]


def _env() -> dict[str, str]:
    # PYTHONPATH or PYTHONPROFILEIMPORTTIME from the caller would change what is measured.
    return {k: v for k, v in os.environ.items()
            if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONPROFILEIMPORTTIME")}


class CaseFailed(Exception):
    """The command exited non-zero; the message is the last line of its stderr."""


def time_once(argv: list[str]) -> float:
    start = time.perf_counter()
    done = subprocess.run(argv, env=_env(), capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]
        raise CaseFailed(last)
    return elapsed


def importtime(module: str, top: int) -> None:
    done = subprocess.run([sys.executable, "-X", "importtime", "-c", f"import {module}"],
                          env=_env(), capture_output=True, text=True)
    rows = []
    for line in done.stderr.splitlines():
        # "import time:  self [us] | cumulative | imported package"
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        self_us, cumulative_us, name = line.removeprefix("import time:").split("|", 2)
        rows.append((int(cumulative_us), int(self_us), name.rstrip()))
    rows.sort(reverse=True)
    print(f"slowest imports of `import {module}` (cumulative ms, self ms):")
    for cumulative, self_us, name in rows[:top]:
        print(f"  {cumulative / 1e3:8.1f}  {self_us / 1e3:7.1f}  {name}")
    if done.returncode != 0:
        # The times of what was imported before the failure are still worth seeing.
        last = (done.stderr.strip().splitlines() or [""])[-1]
        raise SystemExit(f"import {module} failed: {last}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, metavar="N",
                        help="fresh processes per case (default 7)")
    parser.add_argument("--importtime", metavar="MODULE",
                        help="print the slowest imports of MODULE instead of timing the cases")
    parser.add_argument("--top", type=int, default=15,
                        help="rows printed with --importtime (default 15)")
    args = parser.parse_args()
    if args.repeat < 1:
        parser.error(f"--repeat must be at least 1, got {args.repeat}")
    if args.importtime:
        importtime(args.importtime, args.top)
        return
    if not TCAFF.is_file():
        raise SystemExit(f"no tcaff command at {TCAFF}: install the project (make install)")
    print(f"start-up, {args.repeat} fresh processes per case, {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'case':<40} {'median s':>9} {'min s':>7} {'target s':>9}")
    failed = False
    for label, argv, target in CASES:
        try:
            time_once(argv)  # warm the disk caches and the bytecode
            times = [time_once(argv) for _ in range(args.repeat)]
        except CaseFailed as exc:
            # One broken module should not hide the figures of the others.
            print(f"{label:<40} failed: {exc}")
            failed = True
            continue
        median = statistics.median(times)
        verdict = "" if target is None else ("  ok" if median <= target else "  SLOW")
        target_text = "-" if target is None else f"{target:.2f}"
        print(f"{label:<40} {median:9.2f} {min(times):7.2f} {target_text:>9}{verdict}")
    if failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
