"""A live team's costs: latency across processes, a team of 8 at 1 Hz, bytes on the wire.

  latency    one node process (r0) and this process as its neighbour r1, both with maps of
             --objects objects: r1's map goes out, r0 aligns it to its own and publishes the
             alignment, which comes back here. Prints the node's own time from the map
             arriving to the alignment going out, the round trip seen from here (two
             Zenoh hops over loopback included), the aligner alone on the same maps and the
             message's encode + decode; the first --warm exchanges are left out.
  team       --robots node processes replaying a room of that many robots (four_robots'
             world and sensors) at 1 Hz for --seconds, every node aligning to all others.
             Prints per node: alignments made and expected, latency (median, max) and its
             share of one core over the run. It keeps up when every alignment is made and the
             maximum latency stays under the 1 s exchange period.
             With --team-consistency every node also runs the team consistency; with
             --load N, N processes that spin on the CPU run beside the team (a busy robot).
  bytes      the size of a map message at --objects objects and of an alignment message, and
             the team's bandwidth at --robots robots from the maps of the team run.
  consistency  the time of one team-consistency step of a node (TeamConsistency.update over
             every directed pair's alignment, one pair wrong) at 3, 4, 6 and 8 robots.
  state      saving a pair's filter (W = 8, after 40 steps of a 30-object pair): what a
             node's step pays (`TCAFF.snapshot`, the state copied; the file is written on
             another thread) against writing the file on the step (`TCAFF.save`).
  load       five recorded robots (UTIAS MRCLAM, --mrclam) live: each node aligns its
             neighbours' maps as they arrive (--on-arrival), --rate exchanges per second of
             wall time, --load busy processes beside, and robot r2 killed (SIGKILL) at 40 % of
             the run and started again from its saved filters 3 s later. Prints per node:
             maps aligned, skipped (behind: an older map with a newer one waiting), dropped
             as stale, latency median, p95 and max; the restarted node's time to come back
             (start to its presence seen); and the team's availability and false accepts
             against the same aligner offline on the same maps, an alignment standing for
             its pair for 1 s of wall time or until the next (a node behind skips exchanges;
             --seconds caps the run, in run seconds).
  ros2       what `NodeParams(ros2=True)` adds: one accepted alignment published as a ROS 2
             PoseWithCovarianceStamped (message, CDR, attachment, Zenoh put) against the
             team's own message, the map as a MarkerArray at --objects objects, and the
             memory Python holds after --exchanges x 100 more alignments than after the first
             ones (tracemalloc; growth per step would show there).

    python scripts/bench_node.py [--parts latency team bytes consistency state load ros2]
                                 [--objects 100]
                                 [--robots 8] [--seconds 60] [--rate 5] [--exchanges 80]
                                 [--team-consistency] [--load 2] [--guide-radius METRES|none]
                                 [--mrclam ../shared/data/mrclam/MRCLAM_Dataset6]

Timings are wall-clock on a shared machine: run it twice and compare.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table
from tcaff_gtsam.eval.config import load_scenario, override
from tcaff_gtsam.eval.sim.simulate import simulate
from tcaff_gtsam.node import AlignmentMessage, Link, MapMessage, decode, encode
from tcaff_gtsam.node.run import free_ports, node_argv, save_replays, start_team, wait_team

from tcaff_gtsam import ObjectMap
from tcaff_gtsam.geometry import se2_from_params, se2_to_params

TRUE = np.array([3.0, -2.0, 0.7])  # T_r0_r1


def scene(objects: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """`objects` objects in r0's frame and in r1's (30 m square), their widths and heights."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-15, 15, (objects, 2))
    in_r1 = (np.linalg.inv(se2_from_params(TRUE)) @ np.c_[xy, np.ones(objects)].T).T[:, :2]
    in_r1 += rng.normal(0, 0.05, in_r1.shape)
    return (np.c_[xy, np.zeros(objects)], np.c_[in_r1, np.zeros(objects)],
            rng.uniform(0.3, 1.5, objects), rng.uniform(0.3, 1.5, objects))


def aligner_params(guide_radius: float | None):
    """The node's aligner settings with `guide_radius` (None: every search full)."""
    from tcaff_gtsam import FrameAlignerParams

    return FrameAlignerParams(kappa=math.inf, guide_radius=guide_radius)


def aligner_alone(objects: int, steps: int, warm: int, guide_radius: float | None = None
                  ) -> np.ndarray:
    """s per PairwiseAligner.update on the latency maps, in this process (no transport)."""
    from tcaff_gtsam import PairwiseAligner

    mine, theirs, widths, heights = scene(objects)
    aligner = PairwiseAligner(aligner_params(guide_radius))
    times = []
    for k in range(steps):
        seen = np.full(objects, float(k))
        start = time.perf_counter()
        aligner.update(float(k), ObjectMap(mine, widths, heights, seen),
                       ObjectMap(theirs, widths, heights, seen))
        times.append(time.perf_counter() - start)
    return np.array(times[warm:])


def serve(port: int, objects: int, rate: float, guide_radius: float | None) -> None:
    """The node process of `latency`: r0 publishing its map at `rate` Hz until stdin closes,
    then printing its latencies (s) as JSON."""
    from tcaff_gtsam.node import NodeParams, RobotNode

    from tcaff_gtsam.precompile import compile_kernels

    mine, _, widths, heights = scene(objects)
    compile_kernels()
    node = RobotNode("r0", "bench", ["r0", "r1"], Link(listen=(f"127.0.0.1:{port}",)),
                     NodeParams(kappa=math.inf), aligner_params(guide_radius))
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    t0 = time.time()
    while not stop.wait(1.0 / rate):
        t = time.time() - t0
        node.publish(t, ObjectMap(mine, widths, heights, np.full(objects, t)))
    node.close()
    print(json.dumps(list(node.latencies)))


def latency(objects: int, rate: float, exchanges: int, warm: int,
            guide_radius: float | None) -> dict[str, np.ndarray]:
    port = free_ports(1)[0]
    server = subprocess.Popen([sys.executable, __file__, "--serve", str(port), "--objects",
                               str(objects), "--rate", str(rate), "--guide-radius",
                               str(guide_radius).lower()],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    _, theirs, widths, heights = scene(objects)
    sent: dict[int, float] = {}
    back: dict[int, float] = {}

    def arrived(sample) -> None:
        message = decode(sample.payload.to_bytes())
        if isinstance(message, AlignmentMessage):
            back.setdefault(message.neighbour_seq, time.perf_counter())

    with Link(connect=(f"127.0.0.1:{port}",)).open() as session:
        session.declare_subscriber("tcaff/bench/r0/alignment/r1", arrived)
        publisher = session.declare_publisher("tcaff/bench/r1/map")
        session.liveliness().declare_token("tcaff/bench/r1/alive")
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not [  # until the node is up
                r for r in session.liveliness().get("tcaff/bench/r0/alive", timeout=1.0)
                if r.ok is not None]:
            time.sleep(0.1)
        time.sleep(1.0)  # and has published its first map
        for seq in range(exchanges):
            payload = encode(MapMessage("r1", 1, seq, float(seq), theirs, widths, heights,
                                        np.zeros(objects)))
            sent[seq] = time.perf_counter()
            publisher.put(payload)
            time.sleep(1.0 / rate)
        time.sleep(2.0)
    out, _ = server.communicate("", timeout=60)
    node_side = np.array(json.loads(out.strip().splitlines()[-1]))[warm:]
    trip = np.array([back[k] - sent[k] for k in sorted(back) if k >= warm])
    return {"node: map in -> alignment out": node_side,
            "round trip from the neighbour": trip,
            "PairwiseAligner.update alone": aligner_alone(objects, exchanges, warm,
                                                          guide_radius),
            "encode + decode of the map": codec(objects)}


def radius(text: str) -> float | None:
    """--guide-radius: metres, or 'none'."""
    return None if text.lower() == "none" else float(text)


def default_radius() -> float | None:
    from tcaff_gtsam import FrameAlignerParams

    return FrameAlignerParams().guide_radius


def codec(objects: int, repeats: int = 200) -> np.ndarray:
    """s to encode and decode a map message of `objects` objects (the node's own work on a
    message besides aligning it)."""
    _, theirs, widths, heights = scene(objects)
    message = MapMessage("r1", 1, 0, 0.0, theirs, widths, heights, np.zeros(objects))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        decode(encode(message)).object_map(0.0)
        times.append(time.perf_counter() - start)
    return np.array(times)


def consistency_step(robots: int, wanted: bool, repeats: int = 30) -> np.ndarray:
    """s per TeamConsistency.update with every directed pair's alignment known and one pair's
    wrong by 3 m; `wanted`: only the wrong pair's team alignment asked for (what a node with
    team consistency runs after each step of a pair), else every pair's."""
    from types import SimpleNamespace

    from tcaff_gtsam.team import TeamConsistency

    rng = np.random.default_rng(0)
    poses = [se2_from_params(np.r_[rng.uniform(-20, 20, 2), rng.uniform(-np.pi, np.pi)])
             for _ in range(robots)]
    P = np.diag([0.01, 0.01, 1e-4])
    estimates = {}
    for i in range(robots):
        for j in range(robots):
            if i != j:
                x = se2_to_params(np.linalg.inv(poses[i]) @ poses[j]) + rng.normal(0, 0.02, 3)
                if (i, j) in ((0, 1), (1, 0)):
                    x[0] += 3.0
                estimates[(i, j)] = SimpleNamespace(x=x, P=P)
    team = TeamConsistency(robots)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        team.update(estimates, [(0, 1)] if wanted else None)
        times.append(time.perf_counter() - start)
    return np.array(times)


def team(robots: int, seconds: float, team_consistency: bool = False, load: int = 0):
    """(each node's JSON, the simulated run)."""
    config = load_scenario("four_robots")
    config = override(config, "bench", duration=seconds,
                      layout=config.layout.model_copy(update={"robots": robots}))
    run = simulate(config, 0)
    spinners = spinning(load)
    try:
        with tempfile.TemporaryDirectory() as folder:
            return _team(run, robots, seconds, team_consistency, Path(folder)), run
    finally:
        for spinner in spinners:
            spinner.kill()


def _team(run, robots: int, seconds: float, team_consistency: bool, out: Path) -> list[dict]:
    replays = save_replays(run, out / "replay")
    ports = free_ports(robots)
    procs = start_team([node_argv(replays[k], k, robots, "bench8", ports, None, out,
                                  team_consistency=team_consistency)
                        for k in range(robots)], out / "logs")
    codes = wait_team(procs, seconds + 300)
    if any(codes):
        raise SystemExit(f"nodes failed: {codes}; logs in {out / 'logs'}")
    return [json.loads((out / f"r{k}.json").read_text()) for k in range(robots)]


def spinning(load: int) -> list[subprocess.Popen]:
    """`load` processes that keep a core busy each (a robot's other work)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]


#: s of wall time an alignment stands for the pair, until the next one
HOLD = 1.0


def held(rows: dict[str, np.ndarray], neighbour: str, steps: int, hold: int) -> np.ndarray:
    """(steps, 3) what a node's alignments of `neighbour` (its CSV `rows`) tell a user at each
    exchange: the latest one made at or before it, within `hold` exchanges; NaN where that one
    was not accepted, or there is none (a node down, a neighbour silent). Live nodes skip
    exchanges when behind, and a held alignment is what a user has then."""
    mine = rows["neighbour"] == neighbour
    seq = rows["seq"][mine].astype(int)
    x = np.column_stack([rows[c][mine] for c in ("x", "y", "theta")])
    x[rows["accepted"][mine] != 1] = np.nan
    latest = np.full(steps, -1)
    latest[seq] = np.arange(len(seq))  # the last row made at each exchange
    made_at = np.maximum.accumulate(np.where(latest >= 0, np.arange(steps), -1))
    out = np.full((steps, 3), np.nan)
    valid = (made_at >= 0) & (np.arange(steps) - made_at <= hold)
    out[valid] = x[latest[made_at[valid]]]
    return out


def mrclam_offline(data: Path, seconds: float | None):
    """(run, job, methods): MRCLAM `data` (its first `seconds`, None: all) as the default
    config loads it, and TCAFF's offline run of it, scored: what a live team is held to."""
    from tcaff_gtsam.eval.config import MethodsConfig, load_mrclam
    from tcaff_gtsam.eval.dataset_runs import evaluate_run, load_mrclam_run
    from tcaff_gtsam.eval.datasets import mrclam

    config = load_mrclam("default")
    run = load_mrclam_run(mrclam.read_dataset(data), config, config.odometry, 0, seconds)
    job, methods = evaluate_run(run, MethodsConfig(methods=["tcaff"]))
    return run, job, methods


def recorded_team(data: Path, rate: float, busy: int, seconds: float | None,
                  victim: int = 2, kill_share: float = 0.4, down: float = 3.0) -> dict:
    """Five MRCLAM robots live (on arrival) at `rate` exchanges per wall second beside `busy`
    spinning processes, robot `victim` killed at `kill_share` of the run and restarted from
    its state `down` s later: each node's JSON, the restarted node's time to be present
    again, and the offline and live scores of the same run."""
    from tcaff_gtsam.eval.metrics import pooled_metrics
    from tcaff_gtsam.eval.results import thresholds_of
    from tcaff_gtsam.node.link import alive_key
    from tcaff_gtsam.node.results import read_alignments

    run, job, methods = mrclam_offline(data, seconds)
    n, S = run.n_robots, len(run.times)
    spinners = spinning(busy)
    try:
        with tempfile.TemporaryDirectory() as folder:
            out = Path(folder)
            replays = save_replays(run, out / "replay")
            ports = free_ports(n)

            def argv(k: int, start: float | None) -> list[str]:
                return node_argv(replays[k], k, n, "load", ports, start, out, speed=rate,
                                 state=out / "state", on_arrival=True)

            procs = start_team([argv(k, None) for k in range(n)], out / "logs")
            link = Link(connect=(f"127.0.0.1:{ports[0]}",))
            with link.open() as session:
                victim_json = out / f"r{victim}.json"
                while not victim_json.exists():
                    time.sleep(0.05)
                start = json.loads(victim_json.read_text())["start"]
                time.sleep(max(start + kill_share * S / rate - time.time(), 0.0))
                procs[victim].kill()
                procs[victim].wait()
                time.sleep(down)
                spawned = time.monotonic()
                with open(out / "logs" / "restarted.log", "wb") as log:
                    procs[victim] = subprocess.Popen(argv(victim, start), stdout=log,
                                                     stderr=subprocess.STDOUT)
                key = alive_key("load", f"r{victim}")
                while not any(r.ok is not None for r in session.liveliness().get(key,
                                                                                  timeout=0.5)):
                    time.sleep(0.02)
                back_in = time.monotonic() - spawned
            codes = wait_team(procs, S / rate + 300)
            if any(codes):
                raise SystemExit(f"nodes failed: {codes}; logs in {out / 'logs'}")
            stats = [json.loads((out / f"r{k}.json").read_text()) for k in range(n)]
            live = np.stack([held(read_alignments(out / f"r{i}.csv"), f"r{j}", S,
                                  math.ceil(rate * HOLD))
                             for i, j in job.pairs])
    finally:
        for spinner in spinners:
            spinner.kill()
    job.arrays["est_live"] = live
    thresholds = thresholds_of(methods)
    others = [p for p, pair in enumerate(job.pairs) if victim not in pair]
    scores = {}
    for name, method in (("offline", "tcaff"), ("live", "live")):
        traces = job.traces(method)
        scores[name] = pooled_metrics(traces, thresholds)
        scores[f"{name}, pairs without r{victim}"] = pooled_metrics(
            [traces[p] for p in others], thresholds)
    return {"stats": stats, "back_in": back_in, "steps": S, "robots": n, "scores": scores}


def state_costs(repeats: int = 500) -> dict[str, np.ndarray]:
    """Seconds per save of one pair's filter: the snapshot a node's step takes, and the
    whole file written."""
    from tcaff_gtsam import PairwiseAligner, TCAFFParams

    mine, theirs, widths, heights = scene(30)
    aligner = PairwiseAligner(tcaff_params=TCAFFParams(window=8))
    for k in range(40):
        t = float(k)
        aligner.update(t, ObjectMap(mine, widths, heights, np.full(30, t)),
                       ObjectMap(theirs, widths, heights, np.full(30, t)))
    out: dict[str, list[float]] = {"TCAFF.snapshot (a node's step)": [],
                                   "TCAFF.save (the file written)": []}
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "pair.npz"
        for _ in range(repeats):
            start = time.perf_counter()
            aligner.filter.snapshot()
            out["TCAFF.snapshot (a node's step)"].append(time.perf_counter() - start)
            start = time.perf_counter()
            aligner.filter.save(path)
            out["TCAFF.save (the file written)"].append(time.perf_counter() - start)
    return {name: np.array(v) for name, v in out.items()}


def ros2_costs(objects: int, messages: int) -> tuple[dict[str, np.ndarray], int, int]:
    """Seconds per publication of each ROS 2 message kind and of the team's own alignment
    message, and (bytes held after `messages` alignments, bytes held after 2x as many)."""
    import tracemalloc

    from tcaff_gtsam.node.ros2 import Ros2Bridge

    session = Link(listen=(f"127.0.0.1:{free_ports(1)[0]}",)).open()
    bridge = Ros2Bridge(session, "r0")
    rng = np.random.default_rng(0)
    P = np.diag([0.01, 0.02, 0.003])

    def alignment(k: int) -> AlignmentMessage:
        x = TRUE + rng.normal(0, 0.01, 3)
        return AlignmentMessage("r0", 1, k, float(k), "r1", k, float(k), k + 1, 0, True, x, P)

    plain = session.declare_publisher("tcaff/bench/r0/alignment/r1")
    times: dict[str, list[float]] = {"ROS 2 alignment": [], "team alignment (encode + put)": [],
                                     f"ROS 2 map, {objects} objects": []}
    mine, _, widths, heights = scene(objects)
    object_map = ObjectMap(mine, widths, heights, np.zeros(objects))
    for k in range(messages):
        message = alignment(k)
        start = time.perf_counter()
        bridge.alignment(message)
        times["ROS 2 alignment"].append(time.perf_counter() - start)
        start = time.perf_counter()
        plain.put(encode(message))
        times["team alignment (encode + put)"].append(time.perf_counter() - start)
        if k % 20 == 0:
            start = time.perf_counter()
            bridge.object_map(float(k), object_map)
            times[f"ROS 2 map, {objects} objects"].append(time.perf_counter() - start)
    tracemalloc.start()
    held = []
    for _ in range(2):
        for k in range(messages):
            bridge.alignment(alignment(k))
        held.append(tracemalloc.get_traced_memory()[0])
    tracemalloc.stop()
    bridge.close()
    session.close()
    return {name: np.array(v) for name, v in times.items()}, held[0], held[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--parts", nargs="+", default=["latency", "team", "bytes"],
                        choices=["latency", "team", "bytes", "consistency", "state", "load",
                                 "ros2"])
    parser.add_argument("--team-consistency", action="store_true",
                        help="team: every node also runs the team consistency")
    parser.add_argument("--load", type=int, default=0,
                        help="team, load: processes that spin on the CPU beside the team")
    parser.add_argument("--objects", type=int, default=100)
    parser.add_argument("--robots", type=int, default=8)
    parser.add_argument("--seconds", type=float,
                        help="team: run seconds (default 60); load: cap the run (default all)")
    parser.add_argument("--rate", type=float, default=5.0, help="latency, load: exchanges per s")
    parser.add_argument("--exchanges", type=int, default=80, help="latency: maps sent")
    parser.add_argument("--warm", type=int, default=10, help="latency: exchanges left out")
    parser.add_argument("--guide-radius", type=radius, default=default_radius(),
                        help="latency: FrameAlignerParams.guide_radius of the node's aligner, "
                             "metres or 'none' (every search full); default: the library's")
    parser.add_argument("--mrclam", type=Path,
                        default=Path("../shared/data/mrclam/MRCLAM_Dataset6"),
                        help="load: the MRCLAM data set folder")
    parser.add_argument("--serve", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve is not None:
        serve(args.serve, args.objects, args.rate, args.guide_radius)
        return
    console = Console()
    if "latency" in args.parts:
        table = Table(title=f"Latency, {args.objects} objects per map, {args.rate:g} Hz "
                            f"[ms]")
        for column in ("measured", "n", "median", "p95", "max"):
            table.add_column(column, justify="right")
        for name, values in latency(args.objects, args.rate, args.exchanges,
                                    args.warm, args.guide_radius).items():
            ms = 1e3 * values
            table.add_row(name, str(len(ms)), f"{np.median(ms):.2f}",
                          f"{np.percentile(ms, 95):.2f}", f"{ms.max():.2f}")
        console.print(table)
    if "team" in args.parts or "bytes" in args.parts:
        stats, run = team(args.robots, args.seconds or 60.0, args.team_consistency, args.load)
        S = len(run.times)
        table = Table(title=f"{args.robots} robots at 1 Hz for {S} exchanges, each aligning "
                            f"to {args.robots - 1} neighbours"
                            + (", with team consistency" if args.team_consistency else "")
                            + (f", {args.load} busy processes beside" if args.load else ""))
        for column in ("node", "aligned", "expected", "dropped", "latency median [ms]",
                       "latency max [ms]", "CPU [% of a core]"):
            table.add_column(column, justify="right")
        for k, s in enumerate(stats):
            dropped = sum(v for key, v in s.items() if key.startswith("dropped_"))
            table.add_row(f"r{k}", str(s.get("aligned", 0)), str((args.robots - 1) * S),
                          str(dropped), f"{s.get('latency_median_ms', float('nan')):.1f}",
                          f"{s.get('latency_max_ms', float('nan')):.1f}",
                          f"{100 * s['cpu_share']:.1f}")
        console.print(table)
    if "bytes" in args.parts:
        mine, _, widths, heights = scene(args.objects)
        map_bytes = len(encode(MapMessage("r0", 1, 0, 0.0, mine, widths, heights,
                                          np.zeros(args.objects))))
        align_bytes = len(encode(AlignmentMessage("r0", 1, 0, 0.0, "r1", 0, 0.0, 1, 0, True,
                                                  TRUE, np.eye(3))))
        n = args.robots
        kappa = run.settings.kappa
        sent = [len(encode(MapMessage.of("r0", 1, s, float(t), m.recent(float(t), kappa))))
                for robot_maps in run.maps
                for s, (t, m) in enumerate(zip(run.times, robot_maps, strict=True))]
        mean_map = float(np.mean(sent))
        table = Table(title="Bytes (payloads; Zenoh adds a few bytes per message)")
        table.add_column("what")
        table.add_column("bytes", justify="right")
        table.add_row(f"map message, {args.objects} objects", str(map_bytes))
        table.add_row("alignment message", str(align_bytes))
        table.add_row(f"mean map message of the {n}-robot run", f"{mean_map:.0f}")
        published = n * (mean_map + (n - 1) * align_bytes)
        table.add_row(f"team of {n}, published per s (maps + alignments)", f"{published:.0f}")
        table.add_row(f"team of {n}, delivered per s (each map to {n - 1} peers)",
                      f"{n * (n - 1) * mean_map:.0f}")
        console.print(table)
    if "consistency" in args.parts:
        table = Table(title="One team-consistency step: every directed pair known, one wrong "
                            "[ms]")
        for column in ("robots", "every pair: median", "p95", "one pair: median", "p95"):
            table.add_column(column, justify="right")
        for robots in (3, 4, 6, 8):
            cells = []
            for wanted in (False, True):
                ms = 1e3 * consistency_step(robots, wanted)
                cells += [f"{np.median(ms):.2f}", f"{np.percentile(ms, 95):.2f}"]
            table.add_row(str(robots), *cells)
        console.print(table)
    if "state" in args.parts:
        table = Table(title="Saving a pair's filter, W = 8 [ms]")
        for column in ("what", "n", "median", "p95"):
            table.add_column(column, justify="right")
        for name, values in state_costs().items():
            ms = 1e3 * values
            table.add_row(name, str(len(ms)), f"{np.median(ms):.3f}",
                          f"{np.percentile(ms, 95):.3f}")
        console.print(table)
    if "load" in args.parts:
        got = recorded_team(args.mrclam, args.rate, args.load, args.seconds)
        S = got["steps"]
        table = Table(title=f"{got['robots']} MRCLAM robots on arrival, {S} exchanges at "
                            f"{args.rate:g} per s, {args.load} busy processes beside; r2 "
                            f"killed at 40 % and restarted 3 s later")
        for column in ("node", "aligned", "skipped", "stale", "lost by the queue",
                       "latency median [ms]", "p95 [ms]", "max [ms]", "CPU [% of a core]"):
            table.add_column(column, justify="right")
        for k, s in enumerate(got["stats"]):
            table.add_row(f"r{k}", str(s.get("aligned", 0)), str(s.get("skipped", 0)),
                          str(s.get("dropped_stale", 0)), str(s.get("dropped_overflow", 0)),
                          *(f"{s.get(f'latency_{q}_ms', float('nan')):.1f}"
                            for q in ("median", "p95", "max")),
                          f"{100 * s.get('cpu_share', float('nan')):.1f}")
        console.print(table)
        console.print(f"r2 restarted: present again {got['back_in']:.2f} s after its start "
                      f"(r2's counters are those of its second run)")
        table = Table(title="The team against the same aligner offline (every directed pair)")
        for column in ("run", "availability", "false accepts [%]", "estimates"):
            table.add_column(column, justify="right")
        for name, m in got["scores"].items():
            table.add_row(name, f"{m.availability:.3f}", f"{100 * m.false_accept:.2f}",
                          str(m.n_estimates))
        console.print(table)
        live, offline = got["scores"]["live"], got["scores"]["offline"]
        console.print(f"live availability / offline: {live.availability / offline.availability:.3f}"
                      f"; false accepts live - offline: "
                      f"{100 * (live.false_accept - offline.false_accept):+.2f} points")
    if "ros2" in args.parts:
        times, first, second = ros2_costs(args.objects, 100 * args.exchanges)
        table = Table(title="ROS 2 topics: one publication [ms]")
        for column in ("message", "n", "median", "p95", "max"):
            table.add_column(column, justify="right")
        for name, values in times.items():
            ms = 1e3 * values
            table.add_row(name, str(len(ms)), f"{np.median(ms):.3f}",
                          f"{np.percentile(ms, 95):.3f}", f"{ms.max():.3f}")
        console.print(table)
        console.print(f"Python memory held after {100 * args.exchanges} ROS 2 alignments: "
                      f"{first / 1e3:.1f} kB; after {200 * args.exchanges}: {second / 1e3:.1f} kB")


if __name__ == "__main__":
    main()
