"""The `tcaff` commands of a live team of robots over Zenoh: node (one robot), team (a node
process per robot of a simulated or recorded run on this machine, and the table of their
alignments against the truth) and listen (a live table of a team's alignments), with the runs
they replay (simulated, MRCLAM, Kimera-Multi) and their TLS options.
"""

from __future__ import annotations

import atexit
import math
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from .common import (
    _bars,
    _check_clock,
    _check_duration,
    _check_positive,
    _check_seeds,
    _check_speed,
    _console,
    _last_error,
    _refuse,
    _shipped,
    _writable_folder,
    app,
)
from .data import _kimera_bars
from .team_table import _set_aside_previous_run, _team_table


class Ros2Transport(str, Enum):
    """How a node speaks ROS 2 (`--ros2`)."""

    dds = "dds"
    zenoh = "zenoh"


_ROS2_HELP = ("'dds': an rclpy node on the environment's middleware, maps and alignments on "
              "ROS 2 topics alone (docs/ros2.md); 'zenoh': the Zenoh team, also publishing "
              "rmw_zenoh-layout topics (docs/team.md#ros-2).")
_DOMAIN_HELP = "The ROS 2 domain (ROS_DOMAIN_ID) of those topics, 0 to 232."
_PARAMS_FILE_HELP = ("With --ros2 dds: a ROS 2 parameters YAML for /<robot>/tcaff (kappa, "
                     "silence, queue, team_consistency, health_period).")
_TLS_HELP = "PEM file: the team's certificate authority (with --tls-cert, --tls-key: mutual TLS)."
_ON_ARRIVAL_HELP = ("Align each neighbour's map as it arrives, with the robot's latest map, on "
                    "its clock at arrival (as robots with their own exchange counters do; "
                    "behind, a node skips to the newest map) instead of with the map of the "
                    "same exchange.")
_TEAM_HELP = ("Also publish each pair's team-consistent alignment (those failing a cycle of "
              "three robots left out, missing ones chained through a third) on team/<other> "
              "keys and in <robot>.team.csv.")
_SILENCE_HELP = "s without a neighbour's map before its filter steps empty (wall: /--speed)."
_KIMERA_HELP = ("Or a folder of Kimera-Multi rosbags and <robot>_gt_odom.csv files to replay, "
                "mapped through the RGB-D front end (maps saved in OUTPUT/maps/ and reused).")
_KIMERA_TEST_HELP = (f"With --kimera: the Kimera-Multi test YAML or shipped name "
                     f"({_shipped('kimera_multi')}) naming the robots, topics and settings.")


def _tls(ca: Path | None, cert: Path | None, key: Path | None):
    """The team's TLS files, all three or none."""
    from tcaff_gtsam.node.link import TlsFiles

    given = [x is not None for x in (ca, cert, key)]
    if not any(given):
        return None
    if not all(given):
        _refuse("--tls-ca/--tls-cert/--tls-key", [str(x) for x in (ca, cert, key)],
                "give all three or none")
    return TlsFiles(ca, cert, key)


def _transport(ros2: Ros2Transport | None, listen: list[str] | None,
               connect: list[str] | None, tls, identities: bool, params_file: Path | None):
    """The node's Link (Zenoh) or, with --ros2 dds, its DdsTransport."""
    if ros2 is not Ros2Transport.dds:
        from tcaff_gtsam.node.link import Link

        if params_file is not None:
            _refuse("--params-file", str(params_file), "only with --ros2 dds")
        return Link(tuple(listen or ()), tuple(connect or ()), tls,
                    identities=True if identities else None)
    given = {"--listen": listen, "--connect": connect, "--tls-ca/--tls-cert/--tls-key": tls,
             "--tls-identities": identities or None}
    for option, value in given.items():
        if value:
            _refuse(option, str(value), "is for a Zenoh team: --ros2 dds finds its team by "
                    "ROS 2 discovery (see docs/ros2.md for what secures it)")
    from tcaff_gtsam.node.dds import DdsTransport

    return DdsTransport(params_file)


def _check_domain(domain_id: int) -> None:
    """`--domain-id`: a ROS 2 domain, 0 to 232 (as `NodeParams.domain_id`)."""
    if not 0 <= domain_id <= 232:
        _refuse("--domain-id", domain_id, "must be an int in 0..232")


def _simulated(scenario: str, seed: int, duration: float | None):
    """The simulated run of a scenario (capped to `duration` s), the same in every process."""
    _check_seeds([seed])
    _check_duration(duration)
    from ..config import load_scenario, override
    from ..sim.simulate import simulate

    config = load_scenario(scenario)
    if duration is not None:
        config = override(config, "--duration", duration=min(duration, config.duration))
    return simulate(config, seed)


@app.command()
def node(
    robot: Annotated[str, typer.Option(help="This robot's name: r0, r1, ... of the run.")],
    scenario: Annotated[str | None, typer.Option(
        help=f"Replay this robot of a simulated scenario: {_shipped('scenarios')} (or a "
             f"YAML).")] = None,
    replay: Annotated[Path | None, typer.Option(
        help="Replay this robot from a replay file (what `tcaff team` writes to "
             "<output>/replay/).")] = None,
    kimera: Annotated[Path | None, typer.Option(help=_KIMERA_HELP)] = None,
    kimera_test: Annotated[str, typer.Option(help=_KIMERA_TEST_HELP)] = "same_direction",
    team: Annotated[str, typer.Option(help="Team name: keys are tcaff/<team>/<robot>/...")
    ] = "team",
    listen: Annotated[list[str] | None, typer.Option(
        help="host:port to accept peers on (repeat for more).")] = None,
    connect: Annotated[list[str] | None, typer.Option(
        help="host:port of a peer to dial (repeat; retried until it is up).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the simulated run.")] = 0,
    duration: Annotated[float | None, typer.Option(help="Cap the run (s).")] = None,
    speed: Annotated[float, typer.Option(help="Run seconds per wall second.")] = 1.0,
    start_at: Annotated[float | None, typer.Option(
        help="Wall time (epoch s) of the run's first exchange, shared by the team; "
             "default: 1 s after every robot of the run is up. A node started after it "
             "joins where the run is.")] = None,
    output: Annotated[Path, typer.Option(
        help="Folder for <robot>.csv (every alignment), <robot>.json (counters) and, "
             "with --kimera, maps/ (each robot's maps, reused by later runs).")
    ] = Path("results/team"),
    state: Annotated[Path | None, typer.Option(
        help="Folder to save each filter after each step and restore them from on start.")
    ] = None,
    silence: Annotated[float, typer.Option(help=_SILENCE_HELP)] = 3.0,
    clock_offset: Annotated[float, typer.Option(
        help="s added to this robot's clock (to try robots whose clocks differ).")] = 0.0,
    drop_share: Annotated[float, typer.Option(
        help="Share of neighbours' maps to discard on arrival (to try a lossy link).")] = 0.0,
    drop_seed: Annotated[int, typer.Option(help="Seed of the discards.")] = 0,
    on_arrival: Annotated[bool, typer.Option("--on-arrival", help=_ON_ARRIVAL_HELP)] = False,
    team_consistency: Annotated[bool, typer.Option(help=_TEAM_HELP)] = False,
    tls_ca: Annotated[Path | None, typer.Option(help=_TLS_HELP)] = None,
    tls_cert: Annotated[Path | None, typer.Option(
        help="PEM file: this node's certificate, signed by the team's authority.")] = None,
    tls_key: Annotated[Path | None, typer.Option(help="PEM file: this node's private key.")
    ] = None,
    tls_identities: Annotated[bool, typer.Option(
        "--tls-identities", help="Take a robot's maps and alignments only from the "
        "certificate named after it (common name = robot name). Without it this is checked "
        "when this node's certificate names its robot; a shared team certificate is warned "
        "about.")] = False,
    ros2: Annotated[Ros2Transport | None, typer.Option("--ros2", help=_ROS2_HELP)] = None,
    domain_id: Annotated[int, typer.Option(help=_DOMAIN_HELP)] = 0,
    params_file: Annotated[Path | None, typer.Option(help=_PARAMS_FILE_HELP)] = None,
    ros2_objects: Annotated[bool, typer.Option(
        "--ros2-objects", help="Maps from /<robot>/tcaff/objects (MarkerArray) and, over "
        "dds, /<robot>/tcaff/object_cloud (PointCloud2), not a replay (docs/ros2.md); "
        "implies --ros2 zenoh if unset. Needs --members. Runs until Ctrl-C or --duration.")
    ] = False,
    members: Annotated[str | None, typer.Option(
        help="With --ros2-objects: every robot of the team, like r0,r1,r2.")] = None,
    stop_timeout: Annotated[float, typer.Option(
        help="s from SIGTERM or SIGINT to <robot>.json written; past it what is known is "
             "written, marked stop_cut_short, as after a second signal. ros2 launch sends "
             "SIGTERM 5 s after SIGINT, SIGKILL 5 s later.")] = 2.0,  # node.run.STOP_TIMEOUT,
    # not imported: the node's modules load Zenoh, which `tcaff --help` should not wait for
) -> None:
    """One robot of a live team: publishes its maps, aligns to every neighbour's.

    Over Zenoh (--listen/--connect, optionally mutual TLS), or over ROS 2's default middleware
    (--ros2 dds). The robot's maps are replayed (--scenario, --kimera or --replay) on a
    wall-clock schedule that the robots of one run share through --start-at, or taken live
    from a ROS 2 topic (--ros2-objects). From Python, `tcaff_gtsam.node.RobotNode` takes maps
    from a live mapping pipeline.
    """
    sources = [scenario, kimera and str(kimera), replay and str(replay)]
    if ros2_objects:
        from tcaff_gtsam.node.ros2 import check_ros_name

        if any(x is not None for x in sources):
            _refuse("--ros2-objects", sources, "takes the maps from ROS 2: no --scenario, "
                    "--kimera or --replay")
        if not members:
            _refuse("--members", members, "--ros2-objects needs the team's robots, like r0,r1")
        team_robots = [name.strip() for name in members.split(",")]
        for name in (robot, *team_robots):  # before the kernels are loaded
            check_ros_name("--robot" if name == robot else "--members", name)
        _check_duration(duration)
        if speed != 1.0:
            _refuse("--speed", speed, "live maps from ROS 2 run on the wall clock")
    elif sum(x is not None for x in sources) != 1:
        _refuse("--scenario/--kimera/--replay", sources, "give exactly one")
    elif members is not None:
        _refuse("--members", members, "only with --ros2-objects (a replay knows its team)")
    _check_domain(domain_id)
    _check_speed(speed)
    _check_seeds([seed])  # before the endpoints are checked: the run is made after them
    _check_clock(start_at, clock_offset)
    _check_positive("--stop-timeout", stop_timeout, "(s)")
    if state is not None:
        _writable_folder(state, "--state")
    if drop_seed < 0:
        _refuse("--drop-seed", drop_seed, "must be an int >= 0")
    if ros2 is None and ros2_objects:
        ros2 = Ros2Transport.zenoh
    link = _transport(ros2, listen, connect, _tls(tls_ca, tls_cert, tls_key), tls_identities,
                      params_file)
    if ros2 is Ros2Transport.dds:  # DDS discovery runs while the aligner loads
        link.start(robot, domain_id)
        atexit.register(link.close)  # a refusal below leaves no ROS node behind (again: no-op)
    from tcaff_gtsam.node.node import NodeParams
    from tcaff_gtsam.node.replay import RobotReplay, robot_names, run_replay
    from tcaff_gtsam.node.run import live_node, replay_node

    # a replay's maps of exchange k go with the ego map of exchange k; live ones on arrival
    params = NodeParams(silence=silence, lockstep=not (ros2_objects or on_arrival), speed=speed,
                        drop_share=drop_share, seed=drop_seed,
                        team_consistency=team_consistency, ros2=ros2 is not None,
                        domain_id=domain_id, ros2_objects=ros2_objects)
    _writable_folder(output, "--output")
    if ros2_objects:
        node_ = live_node(robot, team, team_robots, link, params, output, state, duration,
                          stop_timeout)
        print(_counted(robot, node_.counters))
        return
    if replay is not None:
        source = RobotReplay.load(replay)
        if robot != source.robots[source.robot]:
            _refuse("--robot", robot, f"{replay} replays {source.robots[source.robot]}")
    else:
        run = (_simulated(scenario, seed, duration) if kimera is None
               else _kimera_run(kimera, kimera_test, duration, output / "maps"))
        names = robot_names(run.n_robots)
        if robot not in names:
            _refuse("--robot", robot, f"the run's robots are {_named(run, names)}")
        source = run_replay(run, names.index(robot), names)
    node_ = replay_node(source, team, link, params, start_at, output, clock_offset, state,
                        stop_timeout=stop_timeout)
    print(_counted(robot, node_.counters))


def _counted(robot: str, counters: dict[str, int]) -> str:
    """A node's last line: its counters, or that it stopped before it counted anything."""
    counts = ", ".join(f"{k} {v}" for k, v in sorted(counters.items()))
    return f"{robot}: {counts or 'stopped before its first exchange'}"


def _kimera_run(data: Path, test: str, duration: float | None, maps: Path):
    """The Kimera-Multi test `test` on the bags in `data` as a recorded run: every robot's
    RGB-D frames through the front end, with progress bars; the maps are saved in `maps` and
    reused by a later call with the same settings and bags."""
    _check_duration(duration)
    if not Path(data).is_dir():
        _refuse("--kimera", str(data), "must be a folder of Kimera-Multi bags")
    from ..config import load_kimera_multi
    from ..datasets import kimera_multi  # the RGB-D front end: loaded only when needed

    config = load_kimera_multi(test)
    if duration is not None:
        config = config.model_copy(update={"duration": duration})
    with _bars() as bars:
        run, _, _ = kimera_multi.load_run(config, data, maps, True, _kimera_bars(bars))
    return run


def _named(run, names: tuple[str, ...]) -> str:
    """"r0, r1" or, for a data set that names its robots, "r0 (acl_jackal2), r1 (...)"."""
    own = getattr(run, "robot_names", ())
    if not own or tuple(own) == tuple(str(k) for k in range(len(names))):
        return ", ".join(names)
    return ", ".join(f"{n} ({o})" for n, o in zip(names, own, strict=True))


def _mrclam_run(data: Path, seed: int, duration: float | None):
    """The UTIAS MRCLAM data set in `data` as a run: default settings, VIO-like odometry."""
    from ..config import load_mrclam
    from ..dataset_runs import load_mrclam_run
    from ..datasets import mrclam

    config = load_mrclam("default")
    return load_mrclam_run(mrclam.read_dataset(data), config, config.odometry, seed,
                           duration or None)


@app.command()
def team(
    scenario: Annotated[str | None, typer.Option(
        help=f"Simulated scenario to replay: {_shipped('scenarios')} (or a YAML).")] = None,
    mrclam: Annotated[Path | None, typer.Option(
        help="Or a UTIAS MRCLAM data set folder to replay (one node per robot; the "
             "'default' MRCLAM settings).")] = None,
    kimera: Annotated[Path | None, typer.Option(help=_KIMERA_HELP)] = None,
    kimera_test: Annotated[str, typer.Option(help=_KIMERA_TEST_HELP)] = "same_direction",
    seed: Annotated[int, typer.Option(
        help="Seed of the simulated run (MRCLAM: of its VIO-like odometry).")] = 0,
    speed: Annotated[float, typer.Option(help="Run seconds per wall second.")] = 1.0,
    duration: Annotated[float | None, typer.Option(help="Cap the run (s).")] = None,
    team_name: Annotated[str, typer.Option("--team", help="Team name.")] = "team",
    base_port: Annotated[int, typer.Option(
        help="Robot k listens on 127.0.0.1:<base-port + k>; 0: free ports.")] = 0,
    output: Annotated[Path, typer.Option(
        help="Folder for every node's CSV, counters, log; a previous run's go to previous/.")
    ] = Path("results/team"),
    drop_share: Annotated[float, typer.Option(
        help="Share of maps each node discards on arrival (a lossy link).")] = 0.0,
    on_arrival: Annotated[bool, typer.Option("--on-arrival", help=_ON_ARRIVAL_HELP)] = False,
    team_consistency: Annotated[bool, typer.Option(help=_TEAM_HELP)] = False,
    silence: Annotated[float, typer.Option(help=_SILENCE_HELP)] = 3.0,
    tls_ca: Annotated[Path | None, typer.Option(help=_TLS_HELP)] = None,
    tls_cert: Annotated[Path | None, typer.Option(help="PEM file: the nodes' certificate.")
    ] = None,
    tls_key: Annotated[Path | None, typer.Option(help="PEM file: the nodes' private key.")
    ] = None,
    ros2: Annotated[Ros2Transport | None, typer.Option("--ros2", help=_ROS2_HELP)] = None,
    domain_id: Annotated[int, typer.Option(help=_DOMAIN_HELP)] = 0,
    bag: Annotated[Path | None, typer.Option(
        help="Also write the run (maps, accepted alignments, truth) as a ROS 2 bag (rosbag2, "
             "MCAP) in this new folder, for ros2 bag play, Foxglove or RViz.")] = None,
) -> None:
    """A live team on this machine: one node process per robot, scored against the truth.

    Starts one node process per robot of a simulated or recorded run (Zenoh over loopback, or
    with --ros2 dds rclpy nodes on ROS 2's default middleware in --domain-id),
    waits for the run to end, and prints every pair's alignments against the truth. Robots are
    named r0, r1, ... in the run's order.

    Kimera-Multi bags (--kimera) go through the RGB-D front end first, once for the team (each
    robot's maps saved in OUTPUT/maps/ and reused by a later run with the same settings and
    bags); the nodes then replay the maps at the 1 Hz exchanges every robot shares."""

    sources = [scenario, mrclam and str(mrclam), kimera and str(kimera)]
    if sum(x is not None for x in sources) != 1:
        _refuse("--scenario/--mrclam/--kimera", sources, "give exactly one")
    _check_speed(speed)
    _check_seeds([seed])
    _check_duration(duration)
    _check_domain(domain_id)
    _check_positive("--silence", silence, "(s of run)")
    if not (math.isfinite(drop_share) and 0 <= drop_share < 1):  # before any node starts
        _refuse("--drop-share", drop_share, "must be a number in [0, 1)")
    if bag is not None:  # checked now, not after the run
        if bag.exists():
            _refuse("--bag", str(bag), "exists; a bag is written to a new folder")
        _writable_folder(bag.parent, "--bag")
    tls = _tls(tls_ca, tls_cert, tls_key)
    dds = ros2 is Ros2Transport.dds
    if dds and (tls is not None or base_port):
        _refuse("--tls-ca/--base-port" if tls is not None else "--base-port",
                str(tls or base_port), "is for a Zenoh team: --ros2 dds uses ROS 2 discovery")
    _writable_folder(output, "--output")
    from tcaff_gtsam.node.replay import robot_names
    from tcaff_gtsam.node.run import free_ports, node_argv, save_replays, start_team, wait_team

    if scenario is not None:
        run = _simulated(scenario, seed, duration)
    elif mrclam is not None:
        run = _mrclam_run(mrclam, seed, duration)
    else:
        run = _kimera_run(kimera, kimera_test, duration, output / "maps")
    n = run.n_robots
    ports = free_ports(n) if base_port == 0 or dds else list(range(base_port, base_port + n))
    if not all(0 < p < 65536 for p in ports):
        _refuse("--base-port", base_port, f"ports {ports[0]}..{ports[-1]} must be in 1..65535")
    replaced = _set_aside_previous_run(output)
    replays = save_replays(run, output / "replay")
    argvs = [node_argv(replays[k], k, n, team_name, ports, None, output, speed, drop_share,
                       tls=tls, silence=silence, team_consistency=team_consistency,
                       domain_id=domain_id if ros2 else None, on_arrival=on_arrival,
                       ros2=ros2.value if ros2 else "zenoh")
             for k in range(n)]
    console = _console()
    if tls is not None:
        console.print(f"warning: every node holds the one certificate {tls.certificate}, so "
                      f"any holder of it can speak for any robot (identities are checked when "
                      f"each robot's certificate names it: start such nodes with tcaff node)",
                      soft_wrap=True, style="yellow")
    if replaced:
        console.print(f"the previous run's results ({replaced} files) moved to "
                      f"{output / 'previous'}", soft_wrap=True)
    console.print(f"robots: {_named(run, robot_names(n))}", soft_wrap=True)
    where = (f"as ROS 2 nodes /r0/tcaff.. in domain {domain_id}" if dds
             else f"on 127.0.0.1:{ports[0]}..{ports[-1]}")
    watch = ("ros2 topic echo /r0/tcaff/alignment/r1" if dds else
             f"tcaff listen --team {team_name} --connect 127.0.0.1:{ports[0]}")
    console.print(f"{n} nodes of team {team_name!r} {where}; {len(run.times)} exchanges at "
                  f"{speed:g}x, about {len(run.times) / speed:.0f} s once every node is up. "
                  f"Watch with: {watch}", soft_wrap=True)
    procs = start_team(argvs, output / "logs")
    codes = wait_team(procs, 180 + len(run.times) / speed)
    failed = [k for k, c in enumerate(codes) if c != 0]
    console.print(_team_table(run, output, robot_names(n)))
    if team_consistency:
        console.print(_team_table(run, output, robot_names(n), team=True))
    if bag is not None:  # what the nodes wrote, failed ones included
        from tcaff_gtsam.node.bag import write_team_bag

        counts = write_team_bag(bag, run, robot_names(n), output)
        console.print(f"bag: {bag} ({sum(counts.values())} messages on {len(counts)} topics; "
                      f"ros2 bag play {bag})", soft_wrap=True)
    if failed:
        from tcaff_gtsam.errors import TcaffError

        logs, err_console = output / "logs", _console(stderr=True)
        for k in failed:  # start_team wrote node k's output to node<k>.log in logs
            err_console.print(f"r{k}: {_last_error(logs / f'node{k}.log', codes[k])}",
                              soft_wrap=True, markup=False)
        raise TcaffError(f"nodes {', '.join(f'r{k}' for k in failed)} failed; see {logs}")
    console.print(f"results: {output}")


@app.command()
def listen(
    team_name: Annotated[str, typer.Option("--team", help="Team name.")] = "team",
    connect: Annotated[list[str] | None, typer.Option(
        help="host:port of a team node to dial (repeat).")] = None,
    listen_on: Annotated[list[str] | None, typer.Option(
        "--listen", help="host:port to accept nodes on.")] = None,
    scenario: Annotated[str | None, typer.Option(
        help="The simulated scenario the team replays: shows each alignment's error.")] = None,
    seed: Annotated[int, typer.Option(help="Its seed.")] = 0,
    seconds: Annotated[float | None, typer.Option(help="Stop after this long (s).")] = None,
    tls_ca: Annotated[Path | None, typer.Option(help=_TLS_HELP)] = None,
    tls_cert: Annotated[Path | None, typer.Option(help="PEM file: this listener's certificate.")
    ] = None,
    tls_key: Annotated[Path | None, typer.Option(help="PEM file: its private key.")] = None,
) -> None:
    """A live table of every pair's latest alignment in a team (Ctrl-C to stop)."""
    import threading

    from rich.live import Live
    from tcaff_gtsam.node.link import Link
    from tcaff_gtsam.node.listener import TeamListener

    link = Link(tuple(listen_on or ()), tuple(connect or ()), _tls(tls_ca, tls_cert, tls_key))
    _check_positive("--seconds", seconds)
    truth = None
    if scenario is not None:
        run = _simulated(scenario, seed, None)
        truth = run.T_true
    stop = threading.Event()
    with TeamListener(team_name, link, truth) as listener, \
            Live(listener.table(), console=_console(), refresh_per_second=4) as live:
        try:
            while not stop.wait(0.25):
                live.update(listener.table())
                if seconds is not None and listener.elapsed() >= seconds:
                    break
        except KeyboardInterrupt:
            pass
        heard = bool(listener.latest)
    if not heard:
        _console(stderr=True).print(
            f"heard no alignment of team {team_name!r} in {listener.elapsed():.0f} s: is a "
            f"node of the team running, and reachable through --connect / --listen?",
            soft_wrap=True, markup=False)
