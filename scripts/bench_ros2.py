"""A team over ROS 2's default middleware (DDS, `tcaff node --ros2 dds`) beside the same team over
Zenoh, on this machine; prints tables.

    python scripts/bench_ros2.py [--parts team,publish,start] [--rate 5] [--load 2] [--repeats 3]
                                 [--mrclam ../shared/data/mrclam/MRCLAM_Dataset6]

Parts:
  team     the five UTIAS MRCLAM robots of the data set, one node process each, aligning maps on
           arrival at --rate exchanges per wall second with --load busy processes beside, over
           DDS and over Zenoh: availability and false accepts against the same aligner offline
           (scored as `bench_node.py --parts load` scores, an alignment standing for its pair
           for 1 s), latency p95 per node, maps lost (sent by a neighbour, never reaching
           the node), maps skipped (reached it with a newer map of their robot waiting: a
           node behind aligns the newest) and maps dropped (refused: stale, duplicate, queue
           full, ...).
  publish  what publishing one accepted alignment costs on top of the alignment (median and
           p95 of 4 000): a DDS node's PoseWithCovarianceStamped (CDR, rclpy publish), and a
           Zenoh node's team message plus its rmw_zenoh-layout ROS 2 message.
  start    node start: spawn of a `tcaff node` process to its first map received by a watcher
           (rclpy subscriber over DDS, Zenoh subscriber over Zenoh), --repeats times each.

The script runs itself inside a network namespace holding only loopback (`node.dds.isolated`):
no DDS packet leaves this machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_node import HOLD, held, mrclam_offline, spinning
from tcaff_gtsam.node.dds import isolated
from tcaff_gtsam.node.run import (
    free_ports,
    node_argv,
    save_replays,
    start_team,
    wait_team,
)

DOMAIN = 61
_INSIDE = "TCAFF_BENCH_ISOLATED"


def team_scores(data: Path, rate: float, busy: int, transport: str) -> dict:
    """The MRCLAM team over `transport` ("dds" or "zenoh"), scored against the offline run."""
    from tcaff_gtsam.eval.metrics import pooled_metrics
    from tcaff_gtsam.eval.results import thresholds_of
    from tcaff_gtsam.node.results import read_alignments

    run, job, methods = mrclam_offline(data, None)
    n, S = run.n_robots, len(run.times)
    spinners = spinning(busy)
    try:
        with tempfile.TemporaryDirectory() as folder:
            out = Path(folder)
            replays = save_replays(run, out / "replay")
            ports = free_ports(n)
            argvs = [node_argv(replays[k], k, n, "bench", ports, None, out, speed=rate,
                               on_arrival=True, ros2=transport,
                               domain_id=DOMAIN if transport == "dds" else None)
                     for k in range(n)]
            codes = wait_team(start_team(argvs, out / "logs"), S / rate + 300)
            if any(codes):
                raise SystemExit(f"{transport} nodes failed: {codes}; logs in {out}/logs")
            stats = [json.loads((out / f"r{k}.json").read_text()) for k in range(n)]
            live = np.stack([held(read_alignments(out / f"r{i}.csv"), f"r{j}", S,
                                  math.ceil(rate * HOLD)) for i, j in job.pairs])
    finally:
        for spinner in spinners:
            spinner.kill()
    job.arrays["est_live"] = live
    thresholds = thresholds_of(methods)
    scores = {name: pooled_metrics(job.traces(method), thresholds)
              for name, method in (("offline", "tcaff"), ("live", "live"))}
    return {"stats": stats, "scores": scores, "steps": S, "robots": n}


def print_team(results: dict[str, dict], rate: float, busy: int) -> None:
    print(f"\nFive MRCLAM robots, {rate:g} exchanges per s, {busy} busy processes beside")
    print("| transport | availability live / offline | false accepts live / offline | "
          "latency p95 per node | maps lost | maps skipped (share) | maps dropped |")
    print("|---|---|---|---|---|---|---|")
    for transport, got in results.items():
        live, offline = got["scores"]["live"], got["scores"]["offline"]
        stats = got["stats"]
        sent = sum(s["maps_sent"] for s in stats)
        # every map reaches a node's worker once: taken (maps_received) or skipped for a
        # newer one of its robot; what neither took nor skipped never arrived
        expected = sum(sent - s["maps_sent"] for s in stats)
        arrived = sum(s.get("maps_received", 0) + s.get("skipped", 0) for s in stats)
        skipped = sum(s.get("skipped", 0) for s in stats)
        dropped = sum(v for s in stats for k, v in s.items() if k.startswith("dropped_"))
        p95 = [s.get("latency_p95_ms", math.nan) / 1e3 for s in stats]
        print(f"| {transport} | {live.availability:.3f} / {offline.availability:.3f} = "
              f"**{live.availability / offline.availability:.3f}** | "
              f"{100 * live.false_accept:.2f} % / {100 * offline.false_accept:.2f} % | "
              f"{min(p95):.3f} to {max(p95):.3f} s | {expected - arrived} of {expected} | "
              f"{skipped} ({100 * skipped / expected:.2f} %) | {dropped} |")


#: a subscriber in a process of its own, over DDS (argv: "dds", topic) or Zenoh ("zenoh",
#: endpoint, key expression); prints "heard" at its first message, then takes the rest
LISTENER = """
import sys
if sys.argv[1] == "dds":
    import rclpy
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    rclpy.init()
    node = Node("publish_listener")
    heard = []
    def take(data):
        if not heard:
            print("heard", flush=True)
        heard.append(1)
    node.create_subscription(PoseWithCovarianceStamped, sys.argv[2], take, QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL), raw=True)
    rclpy.spin(node)
else:
    import threading
    from tcaff_gtsam.node import Link
    first = threading.Event()
    session = Link(connect=(sys.argv[2],)).open()
    session.declare_subscriber(sys.argv[3], lambda sample: first.set())
    first.wait()
    print("heard", flush=True)
    threading.Event().wait()
"""


def publish_costs(messages: int = 4000) -> dict[str, np.ndarray]:
    """s per accepted alignment published: over DDS, and over Zenoh with its ROS 2 topics;
    each with no subscriber, then with one in another process that has received a first
    message (so that it is matched)."""
    from tcaff_gtsam.node import Link, NodeParams, RobotNode
    from tcaff_gtsam.node.dds import DdsTransport
    from tcaff_gtsam.node.messages import AlignmentMessage

    def alignment(k: int) -> AlignmentMessage:
        return AlignmentMessage("r0", 1, k, 1000.0 + k, "r1", k, 1000.0 + k, k, 0, True,
                                np.array([1.0, 2.0, 0.3]), np.eye(3) * 1e-2)

    out = {}
    for matched in (False, True):
        port = free_ports(1)[0]
        for name, link, params, listener in (
                ("DDS (rclpy)", DdsTransport(), NodeParams(domain_id=DOMAIN),
                 ["dds", "/r0/tcaff/alignment/r1"]),
                ("Zenoh + rmw_zenoh layout", Link(listen=(f"127.0.0.1:{port}",)),
                 NodeParams(ros2=True), ["zenoh", f"127.0.0.1:{port}", "**"])):
            with RobotNode("r0", "bench", ["r0", "r1"], link, params) as node:
                transport = node._transport
                heard = None
                if matched:
                    heard = subprocess.Popen([sys.executable, "-c", LISTENER, *listener],
                                             stdout=subprocess.PIPE, text=True)
                    waiting = True
                    while waiting:  # publish until the listener has one
                        transport.put_alignment(alignment(0))
                        waiting = not select.select([heard.stdout], [], [], 0.05)[0]
                    assert heard.stdout.readline().strip() == "heard"
                times = np.empty(messages)
                for k in range(messages):
                    began = time.perf_counter()
                    transport.put_alignment(alignment(k + 1))
                    times[k] = time.perf_counter() - began
                if heard is not None:
                    heard.kill()
                    heard.wait()
            out[(name, "one subscriber" if matched else "no subscriber")] = times
    return out


def start_times(transport: str, repeats: int = 3) -> list[float]:
    """s from spawning a replaying node to a watcher's receiving its first map."""
    from tcaff_gtsam.eval.config import load_scenario, override
    from tcaff_gtsam.eval.sim.simulate import simulate

    run = simulate(override(load_scenario("four_robots"), "bench", duration=60), 0)
    got = []
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder)
        replays = save_replays(run, out / "replay")
        for attempt in range(repeats):
            ports = free_ports(run.n_robots)
            first = []
            if transport == "dds":
                import rclpy
                from rclpy.executors import SingleThreadedExecutor
                from rclpy.node import Node
                from visualization_msgs.msg import MarkerArray

                context = rclpy.Context()
                rclpy.init(context=context, domain_id=DOMAIN)
                watcher = Node("start_watcher", context=context)
                watcher.create_subscription(
                    MarkerArray, "/r1/tcaff/map",
                    lambda m, first=first: first.append(time.monotonic()), 10, raw=True)

                executor = SingleThreadedExecutor(context=context)
                executor.add_node(watcher)

                def spin(executor=executor) -> None:
                    executor.spin_once(timeout_sec=0.01)
            else:
                from tcaff_gtsam.node import Link

                session = Link(listen=(f"127.0.0.1:{ports[0]}",)).open()
                sub = session.declare_subscriber(
                    "tcaff/start/r1/map", lambda s, first=first: first.append(time.monotonic()))

                def spin() -> None:
                    time.sleep(0.01)
            argv = node_argv(replays[1], 1, run.n_robots, "start", ports, time.time(),
                             out / f"{transport}{attempt}", speed=5.0, ros2=transport,
                             domain_id=DOMAIN if transport == "dds" else None)
            spawned = time.monotonic()
            with open(out / f"{transport}{attempt}.log", "wb") as log:
                proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)
            while not first and time.monotonic() < spawned + 60:
                spin()
            got.append(first[0] - spawned if first else math.nan)
            proc.terminate()
            proc.wait(30)
            if transport == "dds":
                executor.shutdown()
                watcher.destroy_node()
                context.try_shutdown()
            else:
                sub.undeclare()
                session.close()
    return got


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--parts", default="team,publish,start")
    parser.add_argument("--rate", type=float, default=5.0)
    parser.add_argument("--load", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3, help="node starts timed (start)")
    parser.add_argument("--mrclam", type=Path,
                        default=Path("../shared/data/mrclam/MRCLAM_Dataset6"))
    args = parser.parse_args()
    if not os.environ.get(_INSIDE):  # every DDS process of the benchmark stays on this machine
        argv, env = isolated([sys.executable, *sys.argv], DOMAIN)
        sys.exit(subprocess.run(argv, env=dict(env, **{_INSIDE: "1"})).returncode)
    parts = args.parts.split(",")
    if "team" in parts:
        print_team({t: team_scores(args.mrclam, args.rate, args.load, t)
                    for t in ("dds", "zenoh")}, args.rate, args.load)
    if "publish" in parts:
        print("\nPublishing one accepted alignment (4 000 each)")
        print("| how | matched | median | p95 |")
        print("|---|---|---|---|")
        for (name, matched), times in publish_costs().items():
            print(f"| {name} | {matched} | {1e3 * np.median(times):.3f} ms | "
                  f"{1e3 * np.percentile(times, 95):.3f} ms |")
    if "start" in parts:
        print(f"\nNode start: spawn to the first map a watcher receives ({args.repeats} each)")
        print("| transport | times | median |")
        print("|---|---|---|")
        for transport in ("dds", "zenoh"):
            times = start_times(transport, args.repeats)
            print(f"| {transport} | {', '.join(f'{t:.2f}' for t in times)} s | "
                  f"{np.nanmedian(times):.2f} s |")


if __name__ == "__main__":
    main()
