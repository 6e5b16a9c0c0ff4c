"""How a node stops under ROS 2 launch: signal -> results written -> exit.

A team of two `tcaff node` processes (r0, r1) replays 30-object maps at 1 Hz over Zenoh on
loopback (--ros2 dds: over ROS 2 DDS, the whole run inside a network namespace that holds only
loopback, which needs root). Once r0 has aligned a few of r1's maps, r0 is stopped the way
`ros2 launch` stops a process: the first signal (--first: SIGINT, launch's, or SIGTERM,
systemd's), SIGTERM --sigterm-timeout s later if it still runs, SIGKILL --sigkill-timeout s
after that (launch's defaults: 5 and 5). Timed from the first signal: when r0's
`<robot>.json` holds its results (its counters, not only its start) and when the process has
exited.

Each case runs with r0's worker healthy and with it stuck: r0's third filter update never
returns (a long update, a frozen callback), while its results so far are done. And each runs
on a quiet machine and beside --load processes that keep a core busy each (started once the
team runs). Prints one row per case, with the range over --repeats runs.

    python scripts/bench_stop.py [--repeats 2] [--load 10] [--stop-timeout S]
                                 [--workers healthy stuck] [--first SIGINT SIGTERM]
                                 [--ros2 zenoh|dds]

--stop-timeout is passed to the node (the node's own default when not given; a node without
the option must be run without it).
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tcaff_gtsam.node.dds import isolated

# the tests' stuck node: what is measured here is what they check
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from stuck_node import DONE, start_pair


def _rows(path: Path) -> int:
    """Data rows of an alignments CSV so far."""
    try:
        return max(len(path.read_text().splitlines()) - 1, 0)
    except OSError:
        return 0


def _results(path: Path) -> dict | None:
    """The node's JSON once it holds its results (not only its start); None before."""
    try:
        outcome = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return outcome if "maps_sent" in outcome else None


def one_stop(folder: Path, stuck: bool, first: signal.Signals, load: int, stop_timeout,
             sigterm_timeout: float, sigkill_timeout: float, dds_domain: int | None) -> dict:
    """One team started, r0 stopped as launch stops it; the timings from the first signal.
    With `dds_domain`, the nodes talk ROS 2 DDS in that domain (the script is then run in a
    loopback-only namespace: see --ros2)."""
    out = folder / "out"
    marker = folder / "stuck"
    procs, _ = start_pair(
        folder, "stop", marker, DONE if stuck else 10**9,
        () if stop_timeout is None else ("--stop-timeout", str(stop_timeout)),
        domain_id=dds_domain, ros2="dds" if dds_domain is not None else "zenoh")
    busy: list[subprocess.Popen] = []
    try:
        deadline = time.monotonic() + 180
        while not (marker.exists() if stuck else _rows(out / "r0.csv") >= DONE + 1):
            if time.monotonic() > deadline or procs[0].poll() is not None:
                raise RuntimeError(f"r0 never got going; see {folder / 'node0.log'}")
            time.sleep(0.05)
        busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                for _ in range(load)]
        time.sleep(2.0 if load else 0.5)
        t0 = time.monotonic()
        procs[0].send_signal(first)
        escalation = [(sigterm_timeout, signal.SIGTERM),
                      (sigterm_timeout + sigkill_timeout, signal.SIGKILL)]
        written = exited = None
        sent = [first.name]
        while exited is None:
            now = time.monotonic() - t0
            if written is None and _results(out / "r0.json") is not None:
                written = now
            if procs[0].poll() is not None:
                exited = now
                break
            if escalation and now >= escalation[0][0]:
                sent.append(escalation[0][1].name)
                procs[0].send_signal(escalation.pop(0)[1])
            time.sleep(0.005)
        outcome = _results(out / "r0.json")
        if written is None and outcome is not None:
            written = exited
        outcome = outcome or {}
        return {"written": written, "exited": exited, "code": procs[0].returncode,
                "signals": sent, "cut_short": bool(outcome.get("stop_cut_short")),
                "aligned": outcome.get("aligned"), "rows": _rows(out / "r0.csv")}
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
        for proc in procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(30)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()


def _span(values: list[float | None]) -> str:
    """"a-b s" over the runs; "lost" where a run never wrote its results."""
    got = [f"{v:.2f}" for v in sorted(v for v in values if v is not None)]
    text = "" if not got else got[0] if got[0] == got[-1] else f"{got[0]}-{got[-1]}"
    lost = len(values) - len(got)
    if lost:
        text = f"{text} ({lost} lost)" if text else "lost"
    return text


def _ended(run: dict) -> str:
    """How the process ended: by itself after which signals, or killed."""
    if run["code"] == -signal.SIGKILL:
        return "SIGKILL"
    return f"{'+'.join(run['signals'])} -> {run['code']}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--load", type=int, default=10)
    parser.add_argument("--stop-timeout", type=float, default=None)
    parser.add_argument("--workers", nargs="+", default=["healthy", "stuck"],
                        choices=["healthy", "stuck"])
    parser.add_argument("--first", nargs="+", default=["SIGINT", "SIGTERM"],
                        choices=["SIGINT", "SIGTERM"])
    parser.add_argument("--sigterm-timeout", type=float, default=5.0)
    parser.add_argument("--sigkill-timeout", type=float, default=5.0)
    parser.add_argument("--ros2", choices=["zenoh", "dds"], default="zenoh",
                        help="dds: the nodes on ROS 2 DDS, the whole run inside a network "
                             "namespace holding only loopback (unshare -n, as root)")
    parser.add_argument("--in-namespace", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    dds_domain = None
    if args.ros2 == "dds":
        dds_domain = 71  # a domain of its own
        if not args.in_namespace:  # again, inside the namespace: no DDS packet leaves it
            argv, env = isolated([sys.executable, __file__, *sys.argv[1:], "--in-namespace"],
                                 dds_domain)
            sys.exit(subprocess.run(argv, env=env).returncode)
        if [name for _, name in socket.if_nameindex()] != ["lo"]:
            sys.exit("--ros2 dds: this network namespace holds more than loopback")
    print("| r0's worker | busy processes | first signal | results written [s] | exit [s] "
          "| ended (signals -> exit code) | cut short noted | aligned / CSV rows |")
    print("|---|---|---|---|---|---|---|---|")
    for worker in args.workers:
        for load in sorted({0, args.load}):
            for first in args.first:
                runs = []
                for _ in range(args.repeats):
                    with tempfile.TemporaryDirectory(prefix="stop-bench-",
                                                     dir="/tmp") as folder:
                        runs.append(one_stop(Path(folder), worker == "stuck",
                                             signal.Signals[first], load, args.stop_timeout,
                                             args.sigterm_timeout, args.sigkill_timeout,
                                             dds_domain))
                ended = ", ".join(sorted({_ended(r) for r in runs}))
                noted = f"{sum(r['cut_short'] for r in runs)} of {len(runs)}"
                counts = ", ".join(f"{r['aligned']} / {r['rows']}" for r in runs)
                print(f"| {worker} | {load} | {first} | {_span([r['written'] for r in runs])} "
                      f"| {_span([r['exited'] for r in runs])} | {ended} | {noted} "
                      f"| {counts} |", flush=True)


if __name__ == "__main__":
    main()
