"""Start-up time of the `tcaff` command and of the package imports, each in a fresh process.

Every case runs once unmeasured (disk caches, bytecode), then N times, each in a new
interpreter; the table gives median and minimum wall time, and the target where the project
sets one. Exits non-zero when a case fails to run (the others are still measured).

A second table times a fresh process's first `PairwiseAligner.update` (two maps of 12 objects):
the import of the core, then the update, whose numba kernels are compiled on an empty cache
("cold": NUMBA_CACHE_DIR pointed at an empty folder, --cold-repeat processes) or loaded from
the cache that `make install` fills (`python -m tcaff_gtsam.precompile`; "cached").

    python scripts/bench_startup.py [--repeat 7] [--cold-repeat 1] [--importtime MODULE [--top 15]]

--importtime MODULE prints instead the slowest imports of `import MODULE` (python -X importtime:
cumulative and own milliseconds, nested imports indented).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
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


#: seconds the first update may take in a new process once the kernels are cached
FIRST_UPDATE_TARGET = 1.0

# A child process: import the core, then one PairwiseAligner.update on two maps that align;
# prints the two durations in seconds.
FIRST_UPDATE = """
import time
start = time.perf_counter()
import numpy as np
from tcaff_gtsam import PairwiseAligner
from tcaff_gtsam.precompile import _maps
imported = time.perf_counter()
maps = _maps(np.random.default_rng(0), 0.0)
aligner = PairwiseAligner()
begin = time.perf_counter()
aligner.update(0.0, *maps)
print(imported - start, time.perf_counter() - begin)
"""


def _env(**extra: str) -> dict[str, str]:
    # PYTHONPATH or PYTHONPROFILEIMPORTTIME from the caller would change what is measured.
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONPROFILEIMPORTTIME",
                        "NUMBA_CACHE_DIR")}
    return env | extra


class CaseFailed(Exception):
    """The command exited non-zero; the message is the last line of its stderr."""


def run_once(argv: list[str], **env: str) -> tuple[float, str]:
    """Wall seconds of one run of argv, and its standard output."""
    start = time.perf_counter()
    done = subprocess.run(argv, env=_env(**env), capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]
        raise CaseFailed(last)
    return elapsed, done.stdout


def time_once(argv: list[str]) -> float:
    return run_once(argv)[0]


def first_update(cold: bool) -> tuple[float, float, float]:
    """(import s, first update s, process wall s) of one fresh process; `cold` compiles the
    kernels into an empty cache folder, else they come from the package's cache."""
    argv = [sys.executable, "-c", FIRST_UPDATE]
    if not cold:
        wall, out = run_once(argv)
    else:
        with tempfile.TemporaryDirectory(prefix="numba-cache-") as cache:
            wall, out = run_once(argv, NUMBA_CACHE_DIR=cache)
    imported, update = (float(x) for x in out.split())
    return imported, update, wall


def print_first_update(repeat: int, cold_repeat: int) -> bool:
    """The first-update table; False when a run failed."""
    print()
    print("first PairwiseAligner.update in a fresh process (median s over the processes)")
    print(f"{'kernels':<10} {'processes':>9} {'import':>8} {'update':>8} {'wall':>8} "
          f"{'target s':>9}")
    try:
        first_update(cold=False)  # fills the package's cache if it is not yet (make install)
        for label, cold, n in (("cold", True, cold_repeat), ("cached", False, repeat)):
            runs = [first_update(cold) for _ in range(n)]
            imported, update, wall = (statistics.median(r[k] for r in runs) for k in range(3))
            target = "-" if cold else f"{FIRST_UPDATE_TARGET:.2f}"
            verdict = "" if cold else ("  ok" if update <= FIRST_UPDATE_TARGET else "  SLOW")
            print(f"{label:<10} {n:>9} {imported:8.2f} {update:8.2f} {wall:8.2f} "
                  f"{target:>9}{verdict}")
    except CaseFailed as exc:
        print(f"first update failed: {exc}")
        return False
    return True


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
    parser.add_argument("--cold-repeat", type=int, default=1, metavar="N",
                        help="fresh processes compiling on an empty cache (default 1; each "
                             "takes seconds)")
    parser.add_argument("--importtime", metavar="MODULE",
                        help="print the slowest imports of MODULE instead of timing the cases")
    parser.add_argument("--top", type=int, default=15,
                        help="rows printed with --importtime (default 15)")
    args = parser.parse_args()
    if args.repeat < 1:
        parser.error(f"--repeat must be at least 1, got {args.repeat}")
    if args.cold_repeat < 1:
        parser.error(f"--cold-repeat must be at least 1, got {args.cold_repeat}")
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
    if not print_first_update(args.repeat, args.cold_repeat):
        failed = True
    if failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
