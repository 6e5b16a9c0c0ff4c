"""A team over ROS 2's default middleware (`tcaff node --ros2 dds`, `node.dds`), checked with
real ROS 2: rclpy subscribers and publishers written here, in processes of their own.

Every ROS 2 process runs inside a network namespace that holds only loopback (`node.dds.
isolated`: `unshare -n`, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a domain of its own per
test): a launcher script per live run runs there and starts the nodes and the rclpy
processes as its children, which see each other; pytest stays outside. The live runs replay
against the clock, waiting on it most of the time, so one module fixture starts them all at
once and each test checks its own; they are marked `realtime`.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from tcaff_gtsam.node import NodeParams, RobotNode, dds, ros2
from tcaff_gtsam.node.dds import DdsTransport, isolated, namespace_problem, ros2_available
from tcaff_gtsam.node.results import read_alignments, row_covariance

from tcaff_gtsam import FrameAlignerParams, ObjectMap, PairwiseAligner
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_from_params

_missing = ros2_available()
_no_namespace = None if _missing else namespace_problem()
live = pytest.mark.skipif(bool(_missing or _no_namespace),
                          reason=f"needs ROS 2 and a network namespace: "
                                 f"{_missing or _no_namespace}")

#: a domain per test, none the other tests of the suite use
DOMAINS = {"team": 41, "objects": 42, "params": 43}


def start_isolated(script: str, args: list[str], domain_id: int) -> subprocess.Popen:
    """Start a Python `script` with `args` in a loopback-only namespace (see the docstring)."""
    argv, env = isolated([sys.executable, "-c", textwrap.dedent(script), *args], domain_id)
    # its own process group: a failed test kills the nodes it started too (`stop`)
    return subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)


def stop(proc: subprocess.Popen) -> None:
    """Kill a run still going and every process it started (its process group)."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()


#: an rclpy subscriber of one alignment topic (reliable, transient local as published, every
#: message kept) and of /diagnostics; prints "ready", then on a line of stdin its JSON
SUBSCRIBER = """
    import json, sys, threading
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped

    rclpy.init()
    node = Node("alignment_watcher")
    qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    got, health = [], []
    def take(m):
        got.append({"stamp": m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec,
                    "frame": m.header.frame_id, "x": m.pose.pose.position.x,
                    "y": m.pose.pose.position.y, "qz": m.pose.pose.orientation.z,
                    "qw": m.pose.pose.orientation.w, "cov": list(m.pose.covariance)})
    node.create_subscription(PoseWithCovarianceStamped, sys.argv[1], take, qos)
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: health.extend(s.name for s in m.status), 10)
    threading.Thread(target=rclpy.spin, args=(node,), daemon=True).start()
    print("ready", flush=True)
    sys.stdin.readline()
    print(json.dumps({"got": got, "health": sorted(set(health))}), flush=True)
"""

#: inside the namespace: the subscriber, then `tcaff team ... --ros2 dds --bag`, then every
#: message of the bag through rclpy's deserialize_message; prints one JSON line
TEAM = """
    import json, subprocess, sys
    subscriber_script, topic, *team = sys.argv[1:]
    sub = subprocess.Popen([sys.executable, "-c", subscriber_script, topic],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert sub.stdout.readline().strip() == "ready"
    done = subprocess.run([sys.executable, "-m", "tcaff_gtsam.eval.cli", *team],
                          capture_output=True, text=True)
    watched = json.loads(sub.communicate("stop\\n", timeout=60)[0].strip().splitlines()[-1])

    import importlib
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader
    bag = team[team.index("--bag") + 1]
    decoded = {}
    with Reader(bag) as reader:
        for connection, _, data in reader.messages():
            package, _, name = connection.msgtype.split("/")
            kind = getattr(importlib.import_module(f"{package}.msg"), name)
            message = deserialize_message(data, kind)
            decoded[connection.topic] = decoded.get(connection.topic, 0) + 1
    print(json.dumps({"code": done.returncode, "stdout": done.stdout, "stderr": done.stderr,
                      "watched": watched, "decoded": decoded}))
"""


def three_robots(folder: Path) -> Path:
    """four_robots with three robots, as a scenario YAML."""
    from tcaff_gtsam.eval.config import _resolve

    text = _resolve("four_robots", "scenarios").read_text()
    path = folder / "three_robots.yaml"
    path.write_text(text.replace("name: four_robots", "name: three_robots")
                    .replace("robots: 4", "robots: 3"))
    return path


def assert_alike(dds: dict[str, np.ndarray], zenoh: dict[str, np.ndarray]) -> None:
    """Two runs' alignments of one robot step for step: the same exchanges, decisions and
    hypotheses, estimates equal up to the float32 of Zenoh's map messages (pairs' rows
    interleave as maps arrive)."""
    for neighbour in set(zenoh["neighbour"]):
        a, b = (np.flatnonzero(rows["neighbour"] == neighbour) for rows in (dds, zenoh))
        for column in ("seq", "step", "accepted", "hypothesis"):
            assert np.array_equal(dds[column][a], zenoh[column][b]), (neighbour, column)
        for column in ("x", "y", "theta"):
            np.testing.assert_allclose(dds[column][a], zenoh[column][b], atol=1e-3,
                                       equal_nan=True)
    assert len(dds["seq"]) == len(zenoh["seq"])


def feed_maps() -> dict[str, np.ndarray]:
    """The maps the rclpy publisher feeds: 30 objects seen by r0 (`mine`) and by r1 (`theirs`,
    float32, in r1's frame: r0's frame moved by `true`, (x m, y m, yaw rad)), 14 exchanges
    1 s apart (`times`, s)."""
    rng = np.random.default_rng(4)
    n, true = 30, np.array([2.0, -1.0, 0.4])
    xy = rng.uniform(-10, 10, (n, 2))
    T = np.linalg.inv(se2_from_params(true))
    mine = np.c_[xy, rng.uniform(0, 1, n)]
    theirs = np.c_[xy @ T[:2, :2].T + T[:2, 2], mine[:, 2]].astype(np.float32)
    sizes = rng.uniform(0.3, 1.5, n).astype(np.float32)
    return {"mine": mine, "theirs": theirs, "sizes": sizes, "times": 1000.0 + np.arange(14),
            "true": true}


@pytest.fixture(scope="module")
def live_runs(tmp_path_factory) -> dict[str, tuple[subprocess.Popen, Path]]:
    """The live runs of this module, started at once (each waits mostly on the clock): the
    three-node team over DDS with its rclpy subscriber, the same team over Zenoh, and the
    two nodes fed by an rclpy publisher; name -> (process, its folder)."""
    folder = tmp_path_factory.mktemp("ros2_dds")
    team, feed = folder / "team", folder / "feed"
    team.mkdir()
    feed.mkdir()
    common = ["--scenario", str(three_robots(team)), "--duration", "30", "--speed", "5",
              "--silence", "10"]
    np.savez(feed / "maps.npz", **feed_maps())
    runs = {
        "dds": (start_isolated(TEAM, [textwrap.dedent(SUBSCRIBER),
                                      ros2.alignment_topic("r0", "r1"), "team", *common,
                                      "--ros2", "dds", "--domain-id", str(DOMAINS["team"]),
                                      "--output", str(team / "dds"), "--bag",
                                      str(team / "bag")], DOMAINS["team"]), team / "dds"),
        "zenoh": (subprocess.Popen([sys.executable, "-m", "tcaff_gtsam.eval.cli", "team",
                                    *common, "--output", str(team / "zenoh")],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   start_new_session=True),
                  team / "zenoh"),
        "feed": (start_isolated(FEED, [str(feed), str(feed / "maps.npz"),
                                       str(DOMAINS["objects"])], DOMAINS["objects"]), feed)}
    yield runs
    for proc, _ in runs.values():
        stop(proc)


def finished(run: tuple[subprocess.Popen, Path]) -> tuple[subprocess.CompletedProcess, Path]:
    """A live run, waited for."""
    proc, folder = run
    stdout, stderr = proc.communicate(timeout=400)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr), folder


@pytest.mark.realtime
@live
def test_a_dds_team_aligns_as_the_zenoh_team_and_rclpy_receives_every_alignment(
        live_runs) -> None:
    """Three `tcaff node --ros2 dds` processes replay a run: an rclpy subscriber in another
    process receives every accepted alignment r0 publishes to r1, equal to r0's CSV rows;
    every node reports its health on /diagnostics; every message of the team's bag
    deserialises with rclpy; and the same team over Zenoh makes the same alignments."""
    done, dds = finished(live_runs["dds"])
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["code"] == 0, report["stdout"][-2000:] + report["stderr"][-2000:]
    # scored against the truth as the Zenoh team is
    assert "against the truth" in " ".join(report["stdout"].split())
    rows = read_alignments(dds / "r0.csv")
    mine = np.flatnonzero((rows["neighbour"] == "r1") & (rows["accepted"] == 1))
    got = report["watched"]["got"]
    assert len(mine) >= 5 and len(got) == len(mine)
    for k, m in zip(mine, got, strict=True):
        assert m["frame"] == "r0/odom"
        assert m["stamp"] == pytest.approx(rows["stamp"][k], abs=1e-9)
        assert [m["x"], m["y"]] == pytest.approx([rows["x"][k], rows["y"][k]], abs=1e-12)
        theta = 2 * np.arctan2(m["qz"], m["qw"])
        assert np.cos(theta - rows["theta"][k]) == pytest.approx(1.0, abs=1e-12)
        cov = np.array(m["cov"]).reshape(6, 6)
        np.testing.assert_allclose(cov[np.ix_([0, 1, 5], [0, 1, 5])], row_covariance(rows, k),
                                   rtol=1e-12)
        assert not cov[2:5].any() and not cov[:, 2:5].any()
    assert {f"tcaff: /r{k}/tcaff" for k in range(3)} <= set(report["watched"]["health"])
    assert report["decoded"][ros2.map_topic("r0")] == 30
    assert report["decoded"][ros2.alignment_topic("r0", "r1")] == len(mine)
    for robot in ("r0", "r1", "r2"):
        counters = json.loads((dds / f"{robot}.json").read_text())
        assert counters["maps_received"] == 60 and not counters.get("errors"), counters
    # the same team over the project's Zenoh session
    over_zenoh, zenoh = finished(live_runs["zenoh"])
    assert over_zenoh.returncode == 0, over_zenoh.stdout[-2000:] + over_zenoh.stderr[-2000:]
    for robot in ("r0", "r1", "r2"):
        assert_alike(read_alignments(dds / f"{robot}.csv"),
                     read_alignments(zenoh / f"{robot}.csv"))


#: inside the namespace: nodes r0 and r1 taking their maps from ROS 2, and an rclpy
#: publisher feeding r0 MarkerArrays and r1 PointCloud2s built with rclpy's own classes
FEED = """
    import signal, subprocess, sys, time
    import numpy as np
    out, maps, domain = sys.argv[1:4]
    nodes = [subprocess.Popen([sys.executable, "-m", "tcaff_gtsam.eval.cli", "node", "--robot",
                               robot, "--ros2", "dds", "--ros2-objects", "--members", "r0,r1",
                               "--domain-id", domain, "--silence", "1000", "--duration", "120",
                               "--output", out]) for robot in ("r0", "r1")]

    import rclpy
    from rclpy.node import Node
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import PointCloud2, PointField
    from visualization_msgs.msg import Marker, MarkerArray

    data = np.load(maps)
    rclpy.init()
    feeder = Node("pipeline")
    markers = feeder.create_publisher(MarkerArray, "/r0/tcaff/objects", 10)
    clouds = feeder.create_publisher(PointCloud2, "/r1/tcaff/object_cloud", 10)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (
            markers.get_subscription_count() and clouds.get_subscription_count()
            and feeder.count_subscribers("/r0/tcaff/map") and
            feeder.count_subscribers("/r1/tcaff/map")):
        time.sleep(0.1)
    time.sleep(1.0)

    def stamp(t):
        return Time(sec=int(t), nanosec=int(round((t - int(t)) * 1e9)))

    def marker_array(t, xyz, size):
        clear = Marker(action=Marker.DELETEALL, id=0)
        clear.header.stamp = stamp(t)
        out = [clear]
        for k, (p, s) in enumerate(zip(xyz, size)):
            m = Marker(action=Marker.ADD, type=Marker.CYLINDER, id=k + 1)
            m.header.stamp, m.header.frame_id = stamp(t), "r0/odom"
            m.pose.position.x, m.pose.position.y, m.pose.position.z = map(float, p)
            m.scale.x = m.scale.y = m.scale.z = float(s)
            out.append(m)
        return MarkerArray(markers=out)

    def cloud(t, xyz, size, bad=False):
        names = ["x", "y", "z", "width", "height"] + ([] if bad else ["last_seen"])
        fields = [PointField(name=n, offset=4 * k, datatype=PointField.FLOAT32, count=1)
                  for k, n in enumerate(names[:5])]
        fields += [PointField(name=n, offset=24, datatype=PointField.FLOAT64, count=1)
                   for n in names[5:]]
        points = np.zeros(len(xyz), dtype={"names": ["p", "s", "t"],
                                           "formats": ["<3f4", "<2f4", "<f8"],
                                           "offsets": [0, 12, 24], "itemsize": 32})
        points["p"], points["s"], points["t"] = xyz, np.c_[size, size], t
        m = PointCloud2(height=1, width=len(xyz), fields=fields, is_bigendian=False,
                        point_step=32, row_step=32 * len(xyz), is_dense=True)
        m.header.stamp, m.header.frame_id = stamp(t), "r1/odom"
        m.data = points.tobytes()
        return m

    for k, t in enumerate(data["times"]):
        markers.publish(marker_array(t, data["mine"], data["sizes"]))
        # r0 aligns r1's maps once it has one of its own (before: counted early), and the
        # first of each type is slow to read on a busy machine
        time.sleep(0.15 if k else 1.0)
        clouds.publish(cloud(t, data["theirs"], data["sizes"]))
        time.sleep(0.35)
    clouds.publish(cloud(t + 1, data["theirs"], data["sizes"], bad=True))
    time.sleep(2.0)
    for node in nodes:
        node.send_signal(signal.SIGTERM)
    print(" ".join(str(node.wait(60)) for node in nodes))
"""


@pytest.mark.realtime
@live
def test_a_node_fed_by_an_rclpy_publisher_aligns_as_one_fed_directly(live_runs) -> None:
    """An rclpy publisher feeds r0 its maps as MarkerArrays and r1 its maps as PointCloud2s
    (float32 centroids and sizes, float64 last_seen), each built with rclpy's message classes;
    the nodes exchange them over DDS. Each of r0's steps equals a PairwiseAligner fed the same
    maps directly at the step's time; a cloud without last_seen is dropped and counted."""
    maps = feed_maps()
    mine, theirs, sizes, times, true = (maps[k] for k in ("mine", "theirs", "sizes", "times",
                                                          "true"))
    n = len(mine)
    done, folder = finished(live_runs["feed"])
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.splitlines()[-1] == "0 0", done.stdout + done.stderr[-3000:]
    rows = read_alignments(folder / "r0.csv")
    assert len(rows["seq"]) == len(times) and (rows["neighbour"] == "r1").all()
    aligner = PairwiseAligner(FrameAlignerParams(kappa=20.0))
    size = sizes.astype(float)
    for k in range(len(rows["seq"])):
        t, seq = rows["stamp"][k], int(rows["seq"][k])
        ego = ObjectMap(mine, size, size, np.full(n, times[seq]))
        other = ObjectMap(theirs.astype(float), size, size, np.full(n, t))
        estimate = aligner.update(t, ego, other)
        assert bool(rows["accepted"][k]) == (estimate is not None)
        if estimate is not None:
            np.testing.assert_allclose([rows[c][k] for c in ("x", "y", "theta")], estimate.x,
                                       rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(row_covariance(rows, k), estimate.P, rtol=1e-9)
    assert rows["accepted"][-1] == 1
    np.testing.assert_allclose([rows[c][-1] for c in ("x", "y", "theta")], true, atol=0.05)
    for robot in ("r0", "r1"):
        counters = json.loads((folder / f"{robot}.json").read_text())
        assert counters["maps_sent"] == len(times), counters
    assert json.loads((folder / "r1.json").read_text())["dropped_malformed"] == 1


def test_a_cloud_of_objects_reads_back_and_bad_ones_are_data_errors() -> None:
    m = ObjectMap(np.arange(12.0).reshape(4, 3), np.ones(4), np.full(4, 2.0),
                  1.7e9 + np.arange(4.0))
    t, back = ros2.object_map_of_cloud(ros2.cloud_message(1.7e9 + 5, "r0/odom", m))
    assert t == 1.7e9 + 5
    for name in ("centroids", "widths", "heights", "last_seen"):
        np.testing.assert_array_equal(getattr(back, name), getattr(m, name))
    bad = ros2.cloud_message(1.0, "r0/odom", m)
    bad.fields = bad.fields[:5]
    with pytest.raises(DataError, match="'last_seen'"):
        ros2.object_map_of_cloud(bad)
    short = ros2.cloud_message(1.0, "r0/odom", m)
    short.data = short.data[:40]
    with pytest.raises(DataError, match="needs 192 bytes"):
        ros2.object_map_of_cloud(short)


def test_a_neighbours_map_reads_back_as_the_exchange_it_was() -> None:
    m = ObjectMap(np.arange(6.0).reshape(2, 3), np.ones(2), np.ones(2), np.array([9.0, 9.5]))
    message = ros2.read_message(ros2.serialize(ros2.map_message(10.0, "r1/odom", m, seq=7,
                                                                boot=4_000_000_000),
                                               ros2.MAP_TYPE), ros2.MAP_TYPE)
    exchange = ros2.exchange_of(message, "r1")
    assert (exchange.sender, exchange.seq, exchange.boot, exchange.stamp) == (
        "r1", 7, 4_000_000_000, 10.0)
    np.testing.assert_allclose(exchange.ages, [1.0, 0.5])
    with pytest.raises(DataError, match="int32"):
        ros2.map_message(10.0, "r1/odom", m, seq=2**31)


def test_dds_options_are_refused_in_one_line(tmp_path: Path, tcaff_main) -> None:
    for args, words in ((["--ros2", "dds", "--listen", "127.0.0.1:7447"], "--listen"),
                        (["--params-file", str(tmp_path / "p.yaml")], "only with --ros2 dds"),
                        (["--ros2", "dds", "--params-file", str(tmp_path / "none.yaml")],
                         "no such file"),
                        (["--ros2", "ddss"], "--ros2")):
        done = tcaff_main("node", "--robot", "r0", "--scenario", "four_robots", "--output",
                          str(tmp_path), *args)
        assert done.returncode == 2 and words in done.stderr, done.stderr
    with pytest.raises(ConfigError, match="health_period"):
        DdsTransport(health_period=0.0)
    if not _missing:  # refused before any ROS node is made
        with pytest.raises(ConfigError, match="domain_id"):
            DdsTransport().start("r0", 233)
        with pytest.raises(ConfigError, match="--robot"):
            DdsTransport().start("r-0", 0)
    if _missing:  # without ROS 2 a DDS node says what to install
        with pytest.raises(ConfigError, match=r"tcaff-gtsam\[ros2\]"):
            RobotNode("r0", "t", ["r0", "r1"], DdsTransport(), NodeParams())


BAD_PARAMS = """
import sys
from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.node.dds import DdsTransport
try:
    DdsTransport(sys.argv[1]).start("r0", int(sys.argv[2]))
except ConfigError as exc:
    print(exc)
    sys.exit(3)
"""


@live
def test_a_params_file_ros_2_cannot_parse_is_named(tmp_path: Path) -> None:
    """rcl refuses it as the node starts: the project's error naming the file, not rclpy's
    RCLError."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("kappa: 20\n/r0/tcaff: {ros__parameters: {kappa: 20}}\n")
    proc = start_isolated(BAD_PARAMS, [str(bad), str(DOMAINS["params"])], DOMAINS["params"])
    try:
        out, err = proc.communicate(timeout=60)
    finally:
        stop(proc)
    assert proc.returncode == 3, err
    assert out.startswith(f"--params-file {str(bad)!r}: ROS 2 refused to start with it"), out


@pytest.mark.parametrize(("given", "expected"), [
    ({}, "ours"),
    ({"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}, "ours"),
    ({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}, None),
    ({"FASTDDS_DEFAULT_PROFILES_FILE": "/their/profile.xml"}, "/their/profile.xml"),
    ({"FASTRTPS_DEFAULT_PROFILES_FILE": "/their/old.xml"}, None),
])
def test_the_node_announces_often_on_fast_dds_unless_told_otherwise(monkeypatch, given,
                                                                     expected):
    """The node's Fast DDS profile is used only where Fast DDS is the middleware and the user
    gave no profile of their own; it exists and is valid XML with the announcements set."""
    from xml.etree import ElementTree

    for name in ("RMW_IMPLEMENTATION", "FASTDDS_DEFAULT_PROFILES_FILE",
                 "FASTRTPS_DEFAULT_PROFILES_FILE"):
        monkeypatch.delenv(name, raising=False)
    for name, value in given.items():
        monkeypatch.setenv(name, value)
    dds._announce_often()
    got = os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE")
    assert got == (str(dds.FASTDDS_PROFILE) if expected == "ours" else expected)
    count = ElementTree.parse(dds.FASTDDS_PROFILE).getroot().find(
        ".//{*}initialAnnouncements/{*}count")
    assert int(count.text) > 5  # more than Fast DDS's own
