"""The team in ROS 2 terms (`node.ros2`, `node.bag`), checked against implementations this
project did not write: rmw_zenoh key expressions and type hashes against pamoja-ros2 and the
values rmw_zenoh's design document and other ROS 2 projects publish; CDR payloads decoded by
rosbags and by mcap-ros2-support; bags read back by rosbags, by mcap's reader and by
mcap-ros2-support's decoder; a live node's topics received by a plain Zenoh subscriber in
another process."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pamoja import ros2 as pamoja
from tcaff_gtsam.node import Link, MapMessage, NodeParams, RobotNode, encode, ros2
from tcaff_gtsam.node.bag import truth_topic, write_team_bag
from tcaff_gtsam.node.messages import AlignmentMessage, MessageError, TeamMessage
from tcaff_gtsam.node.results import TEAM_COLUMNS, AlignmentCsv
from tcaff_gtsam.node.run import free_ports
from team_estimates import edgy, team_takes

from tcaff_gtsam import ObjectMap
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_from_params
from tcaff_gtsam.params import ParameterError

PROPS = settings(max_examples=40, deadline=None)
#: RIHS01 hashes as ROS 2 Jazzy's rosidl computes them, from rmw_zenoh's design document
#: (String) and from ROS 2 projects that list them (the other two)
PUBLISHED_HASHES = {
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "geometry_msgs/msg/PoseWithCovarianceStamped":
        "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e",
    "visualization_msgs/msg/MarkerArray":
        "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
}
names = st.from_regex(r"[A-Za-z][A-Za-z0-9]{0,6}(_[A-Za-z0-9]{1,4}){0,2}", fullmatch=True)


def mcap_decoder(msgtype: str):
    """mcap-ros2-support's decoder of `msgtype`, from its ROS 2 message definition."""
    from mcap_ros2._dynamic import generate_dynamic

    definition, _ = ros2._store().generate_msgdef(msgtype, ros_version=2)
    return generate_dynamic(msgtype, definition)[msgtype]


# -- names, keys, hashes, tokens ----------------------------------------------------------------


def test_type_hashes_are_the_ones_rosidl_publishes():
    for msgtype, published in PUBLISHED_HASHES.items():
        assert ros2.type_hash(msgtype) == published
        assert pamoja.type_hash_digest(ros2.type_hash(msgtype)) == bytes.fromhex(published[7:])


@PROPS
@given(domain=st.integers(0, 232), robot=names, neighbour=names)
def test_keys_are_the_ones_an_independent_rmw_zenoh_implementation_builds(domain, robot,
                                                                          neighbour):
    topics = [(ros2.map_topic(robot), ros2.MAP_TYPE),
              (ros2.objects_topic(robot), ros2.MAP_TYPE),
              (ros2.alignment_topic(robot, neighbour), ros2.ALIGNMENT_TYPE),
              (ros2.team_topic(robot, neighbour), ros2.ALIGNMENT_TYPE),
              (truth_topic(robot, neighbour), ros2.ALIGNMENT_TYPE)]
    for topic, msgtype in topics:
        assert pamoja.is_valid_name(topic) and pamoja.is_fully_qualified(topic)
        assert ros2.topic_key(domain, topic, msgtype) == pamoja.entity_key(
            domain, topic, msgtype, ros2.type_hash(msgtype))


def test_liveliness_tokens_are_the_design_documents():
    string = "std_msgs/msg/String"
    assert (ros2.entity_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 0, "NN", "", "listener")
            == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener")
    assert (ros2.entity_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 10, "MS", "",
                              "listener", "/chatter", string)
            == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
               "std_msgs::msg::dds_::String_/" + PUBLISHED_HASHES[string] + "/::,10:,:,:,,")
    token = ros2.entity_token(0, "ab", 0, 3, "MP", "/r0", "tcaff", "/r0/tcaff/map",
                              ros2.MAP_TYPE)
    assert f"/%r0/tcaff/{pamoja.percent_mangle('/r0/tcaff/map')}/" in token


@pytest.mark.parametrize("name", ["r-1", "1r", "a__b", "", "r/1", "_r"])
def test_a_name_that_is_no_ros2_token_is_refused(name):
    with pytest.raises(ConfigError, match="ROS 2 name token"):
        ros2.check_ros_name("--robot", name)


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"ros2": True, "domain_id": 233}, "domain_id"), ({"ros2": True, "domain_id": -1},
                                                      "domain_id"),
    ({"ros2_objects": True}, "ros2_objects"), ({"ros2": 1}, "ros2"),
    ({"ros2": True, "ros2_objects": True, "lockstep": True}, "lockstep=False")])
def test_node_params_refuse_bad_ros2_settings(kwargs, field):
    with pytest.raises(ParameterError, match=field):
        NodeParams(**kwargs)


@PROPS
@given(seq=st.integers(-2**63, 2**63 - 1), stamp=st.integers(-2**63, 2**63 - 1),
       gid=st.binary(min_size=16, max_size=16))
def test_attachments_round_trip(seq, stamp, gid):
    data = ros2.attachment(seq, stamp, gid)
    assert len(data) == 33
    assert ros2.decode_attachment(data) == (seq, stamp, gid)


@pytest.mark.parametrize("data", [b"", bytes(32), bytes(34), bytes(16) + b"\x08" + bytes(16)])
def test_a_bad_attachment_is_a_message_error(data):
    with pytest.raises(MessageError):
        ros2.decode_attachment(data)


# -- payloads -----------------------------------------------------------------------------------


finite = st.floats(-1e4, 1e4, allow_nan=False)


@PROPS
@given(x=st.tuples(finite, finite, st.floats(-3.1, 3.1)), a=st.lists(finite, min_size=9,
                                                                      max_size=9),
       t=st.floats(0, 2e9))
def test_an_alignment_decodes_with_rosbags_and_mcap_ros2_support(x, a, t):
    x = np.array(x)
    A = np.array(a).reshape(3, 3) * 1e-2
    P = A @ A.T + 1e-6 * np.eye(3)
    data = ros2.serialize(ros2.pose_message(t, "r0/odom", x, P), ros2.ALIGNMENT_TYPE)
    for decoded in (ros2.read_message(data, ros2.ALIGNMENT_TYPE),
                    mcap_decoder(ros2.ALIGNMENT_TYPE)(data)):
        assert decoded.header.frame_id == "r0/odom"
        stamp = decoded.header.stamp
        assert 0 <= stamp.nanosec < 10**9
        assert stamp.sec + 1e-9 * stamp.nanosec == pytest.approx(t, abs=2e-9 * max(1, t))
        pose = decoded.pose.pose
        assert (pose.position.x, pose.position.y, pose.position.z) == (x[0], x[1], 0.0)
        q = pose.orientation
        assert (q.x, q.y) == (0.0, 0.0)
        assert 2 * np.arctan2(q.z, q.w) == pytest.approx(x[2], abs=1e-12)
        covariance = np.array(decoded.pose.covariance).reshape(6, 6)
        keep = [0, 1, 5]
        np.testing.assert_array_equal(covariance[np.ix_(keep, keep)], P)
        covariance[np.ix_(keep, keep)] = 0
        assert not covariance.any()


@PROPS
@given(n=st.integers(0, 12), seed=st.integers(0, 2**32 - 1), t=st.floats(1, 1e6))
def test_a_map_decodes_with_both_and_reads_back_as_the_same_object_map(n, seed, t):
    rng = np.random.default_rng(seed)
    sent = ObjectMap(rng.uniform(-50, 50, (n, 3)), rng.uniform(0.1, 3, n),
                     rng.uniform(0.1, 3, n), t - rng.uniform(0, 10, n))
    data = ros2.serialize(ros2.map_message(t, "r3/odom", sent), ros2.MAP_TYPE)
    other = mcap_decoder(ros2.MAP_TYPE)(data)
    assert len(other.markers) == n + 1 and other.markers[0].action == 3  # DELETEALL
    assert all(m.header.frame_id == "r3/odom" and m.type == 3 for m in other.markers)
    got_t, got = ros2.object_map_of(ros2.read_message(data, ros2.MAP_TYPE))
    assert got_t == pytest.approx(t, abs=1e-9 * t)
    np.testing.assert_array_equal(got.centroids, sent.centroids)
    np.testing.assert_array_equal(got.widths, sent.widths)
    np.testing.assert_array_equal(got.heights, sent.heights)
    np.testing.assert_allclose(got.last_seen, sent.last_seen, atol=1e-9 * t)


@pytest.mark.parametrize("t", [-2.0**31 - 1, 2.0**31, 3e9, float("nan"), float("inf")])
def test_a_time_no_ros2_stamp_holds_is_a_data_error(t):
    with pytest.raises(DataError, match="int32 seconds"):
        ros2.pose_message(t, "r0/odom", np.zeros(3), np.eye(3))


def test_bytes_that_are_no_marker_array_are_refused():
    with pytest.raises(MessageError, match="MarkerArray"):
        ros2.read_message(b"\x00\x01\x00\x00garbage", ros2.MAP_TYPE)
    empty = ros2.read_message(ros2.serialize(ros2._store().types[ros2.MAP_TYPE](markers=[]),
                                             ros2.MAP_TYPE), ros2.MAP_TYPE)
    with pytest.raises(DataError, match="no map time"):
        ros2.object_map_of(empty)


@PROPS
@given(xy=st.lists(edgy, min_size=2, max_size=2), yaw=st.floats(-3.1, 3.1),
       entries=st.lists(edgy, min_size=9, max_size=9), spd=st.booleans())
@example(xy=[1.0, 2.0], yaw=0.3, entries=[-1.0, 0, 0, 0, -1.0, 0, 0, 0, -1.0], spd=False)
@example(xy=[1.0, 2.0], yaw=0.3, entries=[1.0, 0.5, 0, 0, 1.0, 0, 0, 0, 1.0], spd=False)
def test_an_alignment_topic_is_taken_exactly_when_the_team_consistency_takes_it(xy, yaw,
                                                                                 entries, spd):
    """A DDS node hands every alignment it hears to TeamConsistency.update, which used to
    refuse negative or asymmetric covariances alignment_of had let in, and with them every
    later team step."""
    x = np.array([*xy, yaw])
    P = np.array(entries).reshape(3, 3)
    if spd:  # well-formed ones too, beside the raw draws
        P = np.diag(np.abs(P.diagonal())) + np.eye(3)
    message = ros2.pose_message(5.0, "r0/odom", x, P)
    taken = ros2.alignment_of(message, "r0", "r1") if team_takes(x, P) else None
    if taken is None:
        with pytest.raises(MessageError) as caught:
            ros2.alignment_of(message, "r0", "r1")
        assert caught.value.reason == "malformed"
    else:
        np.testing.assert_array_equal(taken.P, P)
        np.testing.assert_allclose(taken.x, x, atol=1e-12)


@PROPS
@given(q=st.lists(st.one_of(st.floats(-1.1, 1.1), st.floats(allow_nan=True, allow_infinity=True),
                            st.sampled_from([0.0, 1e200, -1e200])), min_size=4, max_size=4))
@example(q=[0.0, 0.0, 1e200, 1e200])  # squared: OverflowError
@example(q=[0.0, 0.0, np.sin(0.15), np.cos(0.15)])
@example(q=[0.0, 0.0, 1.004 * np.sin(2.5), 1.004 * np.cos(2.5)])  # within tf2's tolerance
def test_an_alignments_orientation_is_a_unit_quaternion_or_the_message_is_malformed(q):
    message = ros2.pose_message(5.0, "r0/odom", np.array([1.0, 2.0, 0.3]), np.eye(3))
    o = message.pose.pose.orientation
    o.x, o.y, o.z, o.w = q
    unit = bool(np.all(np.abs(q) <= 1.1)) and abs(np.dot(q, q) - 1.0) <= 0.01
    if not unit:
        with pytest.raises(MessageError) as caught:
            ros2.alignment_of(message, "r0", "r1")
        assert caught.value.reason == "malformed"
        return
    x, y, z, w = np.array(q) / np.linalg.norm(q)  # the rotation it stands for
    yaw = ros2.alignment_of(message, "r0", "r1").x[2]
    assert yaw == pytest.approx(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)),
                                abs=1e-12)


@PROPS
@given(text=st.text(st.characters(exclude_categories=("Cs",)), max_size=12),
       seq=st.integers(-2**31, 2**31 - 1))
@example(text="\u00b2", seq=3)   # '²': a digit to str.isdigit, not to int()
@example(text="4000000000", seq=-1)
def test_a_maps_exchange_counter_and_boot_number_are_read_or_the_map_is_malformed(text, seq):
    m = ObjectMap(np.zeros((1, 3)), np.ones(1), np.ones(1), np.full(1, 9.0))
    sent = ros2.map_message(10.0, "r1/odom", m, boot=0)
    sent.markers[0].id, sent.markers[0].text = seq, text
    message = ros2.read_message(ros2.serialize(sent, ros2.MAP_TYPE), ros2.MAP_TYPE)
    if seq < 0:
        with pytest.raises(MessageError, match="exchange counter, is -") as caught:
            ros2.exchange_of(message, "r1")
        assert caught.value.reason == "malformed"
        return
    exchange = ros2.exchange_of(message, "r1")
    decimal = text.isascii() and text.isdigit() and int(text) < 2**32
    assert (exchange.seq, exchange.boot) == (seq, int(text) if decimal else 0)


# -- a live node --------------------------------------------------------------------------------

TRUE = np.array([2.0, -1.0, 0.4])  # T_r0_r1 as (x, y, theta)
SUBSCRIBER = textwrap.dedent("""
    import json, sys, time
    import zenoh
    from mcap_ros2._dynamic import generate_dynamic
    from rosbags.typesys import Stores, get_typestore

    port, key, token_prefix, msgtype = sys.argv[1:5]
    store = get_typestore(Stores.ROS2_JAZZY)
    decode = generate_dynamic(msgtype, store.generate_msgdef(msgtype, ros_version=2)[0])[msgtype]
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)
    got = []

    def take(sample):
        m = decode(sample.payload.to_bytes())
        att = sample.attachment.to_bytes()
        got.append({"seq": int.from_bytes(att[:8], "little"), "gid_len": att[16],
                    "frame": m.header.frame_id, "x": m.pose.pose.position.x,
                    "y": m.pose.pose.position.y, "qz": m.pose.pose.orientation.z,
                    "qw": m.pose.pose.orientation.w, "cov": list(m.pose.covariance)})

    sub = session.declare_subscriber(key, take)
    print("ready", flush=True)
    sys.stdin.readline()  # the test has driven the node
    time.sleep(0.5)
    tokens = sorted(str(r.ok.key_expr) for r in
                    session.liveliness().get(token_prefix + "/**", timeout=2.0)
                    if r.ok is not None)
    print(json.dumps({"got": got, "tokens": tokens}), flush=True)
    session.close()
""")


class Ros2Team:
    """A RobotNode r0 with ROS 2 topics and a raw session speaking for r1."""

    def __init__(self, params: NodeParams) -> None:
        self.port = free_ports(1)[0]
        self.got: list[AlignmentMessage] = []
        self.node = RobotNode("r0", "ros", ["r0", "r1"],
                              Link(listen=(f"127.0.0.1:{self.port}",)), params,
                              on_alignment=self.got.append)
        self.sender = Link(connect=(f"127.0.0.1:{self.port}",)).open()
        self._token = self.sender.liveliness().declare_token("tcaff/ros/r1/alive")
        rng = np.random.default_rng(3)
        n = 30
        xy = rng.uniform(-10, 10, (n, 2))
        in_r1 = (np.linalg.inv(se2_from_params(TRUE)) @ np.c_[xy, np.ones(n)].T).T[:, :2]
        self.mine, self.theirs = np.c_[xy, np.zeros(n)], np.c_[in_r1, np.zeros(n)]
        self.sizes = rng.uniform(0.3, 1.5, n)
        deadline = time.monotonic() + 20
        while "r1" not in self.node.present(0.5) and time.monotonic() < deadline:
            time.sleep(0.05)

    def ego_map(self, t: float) -> ObjectMap:
        return ObjectMap(self.mine, self.sizes, self.sizes, np.full(len(self.sizes), t))

    def send(self, seq: int, stamp: float) -> None:
        n = len(self.sizes)
        before = self.node.counters["maps_received"]
        self.sender.put("tcaff/ros/r1/map", encode(MapMessage(
            "r1", 1, seq, stamp, self.theirs, self.sizes, self.sizes, np.zeros(n))))
        deadline = time.monotonic() + 10
        while self.node.counters["maps_received"] == before and time.monotonic() < deadline:
            time.sleep(0.005)
        self.node.wait_idle()

    def close(self) -> None:
        self.sender.close()
        self.node.close()


def test_a_plain_zenoh_subscriber_in_another_process_decodes_a_live_nodes_alignments(
        tmp_path):
    team = Ros2Team(NodeParams(silence=2.0, ros2=True, domain_id=7))
    listener, errors = None, open(tmp_path / "stderr.txt", "w+")

    def errors_text() -> str:
        return (tmp_path / "stderr.txt").read_text()

    try:
        key = ros2.topic_key(7, ros2.alignment_topic("r0", "r1"), ros2.ALIGNMENT_TYPE)
        listener = subprocess.Popen(
            [sys.executable, "-c", SUBSCRIBER, str(team.port), key, "@ros2_lv/7",
             ros2.ALIGNMENT_TYPE], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=errors, text=True)
        assert listener.stdout.readline().strip() == "ready", errors_text()
        time.sleep(1.0)  # the subscriber's declaration reaches the node
        for k in range(14):
            team.node.publish(10.0 + k, team.ego_map(10.0 + k))
            team.node.wait_idle()
            team.send(k, 10.0 + k)
        # a time ROS cannot stamp: the team's map goes out, the ROS 2 messages are counted
        team.node.publish(3e9, team.ego_map(3e9))
        team.node.wait_idle()
        out, _ = listener.communicate("stop\n", timeout=90)
        report = json.loads(out.strip().splitlines()[-1])
    finally:
        if listener is not None:
            listener.kill()
        errors.close()
        team.close()
        team.close()  # closing twice is harmless
    err = errors_text()
    # the map at 3e9 s and the alignment the silent neighbour's filter then held
    assert team.node.counters["maps_sent"] == 15 and team.node.counters["ros2_errors"] == 2
    # only accepted alignments go out on ROS 2, and none at a time it cannot stamp
    accepted = [m for m in team.got if m.accepted and m.stamp < 2**31]
    got = report["got"]
    # ROS 2 sequence numbers count the publisher's messages from 1; the subscriber may have
    # come up after the first ones, never miss one after that
    assert len(got) >= 3, err
    assert [g["seq"] for g in got] == list(range(len(accepted) - len(got) + 1,
                                                  len(accepted) + 1))
    for g in got:
        sent = accepted[g["seq"] - 1]
        assert g["gid_len"] == 16 and g["frame"] == "r0/odom"
        assert (g["x"], g["y"]) == (sent.x[0], sent.x[1])
        assert 2 * np.arctan2(g["qz"], g["qw"]) == pytest.approx(sent.x[2], abs=1e-12)
        cov = np.array(g["cov"]).reshape(6, 6)
        np.testing.assert_array_equal(cov[np.ix_([0, 1, 5], [0, 1, 5])], sent.P)
    np.testing.assert_allclose([got[-1]["x"], got[-1]["y"]], TRUE[:2], atol=0.05)
    kinds = {token.split("/")[5] for token in report["tokens"]}
    assert kinds == {"NN", "MP"}, report["tokens"]
    assert any(token.endswith(f"/{ros2.type_hash(ros2.ALIGNMENT_TYPE)}/{ros2.QOS}") and
               "/%r0%tcaff%alignment%r1/" in token for token in report["tokens"])


def test_a_node_takes_its_map_from_the_ros2_objects_topic_and_counts_bad_messages():
    team = Ros2Team(NodeParams(silence=2.0, ros2=True, ros2_objects=True))
    key = ros2.topic_key(0, ros2.objects_topic("r0"), ros2.MAP_TYPE)
    try:
        for k in range(12):
            data = ros2.serialize(ros2.map_message(10.0 + k, "r0/odom", team.ego_map(10.0 + k)),
                                  ros2.MAP_TYPE)
            team.sender.put(key, data)
            deadline = time.monotonic() + 10
            while team.node.counters["maps_sent"] <= k and time.monotonic() < deadline:
                time.sleep(0.005)
            team.node.wait_idle()
            team.send(k, 10.0 + k)
        team.sender.put(key, b"not a marker array")
        deadline = time.monotonic() + 10
        while not team.node.counters["dropped_malformed"] and time.monotonic() < deadline:
            time.sleep(0.005)
    finally:
        team.close()
    c = team.node.counters
    assert c["maps_sent"] == 12 and c["aligned"] == 12 and c["dropped_malformed"] == 1
    np.testing.assert_allclose(team.node.latest["r1"].x, TRUE, atol=0.05)


# -- bags ---------------------------------------------------------------------------------------


def test_a_team_bag_reads_back_with_rosbags_mcap_and_mcap_ros2_support(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.rosbag2 import Reader
    from tcaff_gtsam.eval.config import load_scenario, override
    from tcaff_gtsam.eval.sim.simulate import simulate

    run = simulate(override(load_scenario("four_robots"), "test", duration=6), 0)
    names = ("r0", "r1", "r2", "r3")
    results = tmp_path / "team"
    results.mkdir()
    P = np.array([[0.01, 0.004, -0.001], [0.004, 0.02, 0.002], [-0.001, 0.002, 0.003]])
    for i, robot in enumerate(names):  # r0's node accepted its alignment to r1 from step 2
        rows = AlignmentCsv(results / f"{robot}.csv")
        for k, t in enumerate(run.times):
            ok = robot == "r0" and k >= 2
            x = np.array([1.0 + k, 2.0, 0.5]) if ok else np.full(3, np.nan)
            rows.write(AlignmentMessage(robot, 1, k, float(t), names[(i + 1) % 4], k, float(t),
                                        k + 1, 0 if ok else -1, ok, x,
                                        P if ok else np.full((3, 3), np.nan)))
        rows.close()
    team_rows = AlignmentCsv(results / "r1.team.csv", TEAM_COLUMNS)
    team_rows.write(TeamMessage("r1", 1, 3, float(run.times[3]), "r3", ("r2",), True,
                                np.array([4.0, 5.0, -0.2]), P))
    team_rows.close()
    bag = tmp_path / "bag"
    counts = write_team_bag(bag, run, names, results)
    S = len(run.times)
    assert counts["/r0/tcaff/alignment/r1"] == S - 2 and counts["/r1/tcaff/team_alignment/r3"] == 1
    assert all(counts[ros2.map_topic(r)] == S for r in names)
    assert "/r1/tcaff/alignment/r2" not in counts  # nothing accepted there
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/r0/tcaff/map"] == ros2.MAP_TYPE
        assert types[truth_topic("r0", "r1")] == ros2.ALIGNMENT_TYPE
        assert reader.message_count == sum(counts.values())
        truth = [ros2._store().deserialize_cdr(data, c.msgtype) for c, _, data in
                 reader.messages([c for c in reader.connections
                                  if c.topic == truth_topic("r0", "r2")])]
    T = run.T_true(0, 2)
    finite = [k for k in range(S) if np.all(np.isfinite(T[k]))]
    assert [m.pose.pose.position.x for m in truth] == [T[k][0, 2] for k in finite]
    mcap_file = next(bag.glob("*.mcap"))
    with open(mcap_file, "rb") as file:
        reader = make_reader(file, decoder_factories=[DecoderFactory()])
        schemas = {s.name: s.encoding for s in reader.get_summary().schemas.values()}
        assert schemas == {ros2.MAP_TYPE: "ros2msg", ros2.ALIGNMENT_TYPE: "ros2msg"}
        decoded = [(c.topic, m) for _, c, _, m in reader.iter_decoded_messages(
            topics=["/r0/tcaff/alignment/r1", "/r1/tcaff/team_alignment/r3"])]
    first = next(m for topic, m in decoded if topic == "/r0/tcaff/alignment/r1")
    assert (first.pose.pose.position.x, first.header.frame_id) == (3.0, "r0/odom")
    covariance = np.reshape(first.pose.covariance, (6, 6))
    np.testing.assert_array_equal(covariance[np.ix_([0, 1, 5], [0, 1, 5])], P)
    assert np.count_nonzero(covariance) == np.count_nonzero(P)
    with pytest.raises(ConfigError, match="exists"):
        write_team_bag(bag, run, names, results)


@pytest.mark.slow
def test_tcaff_team_with_ros2_writes_a_bag_of_what_its_nodes_wrote(tmp_path, tcaff_main):
    """`tcaff team --ros2 --bag --on-arrival`: the nodes run with ROS 2 topics on, aligning
    maps as they arrive (stamped on the ego clock at arrival, between the exchanges), and the
    bag holds every accepted alignment of their CSVs and every exchange's maps."""
    from rosbags.rosbag2 import Reader
    from tcaff_gtsam.node.results import read_alignments

    out, bag = tmp_path / "team", tmp_path / "bag"
    # indoor_return: the robots' filters accept from about the 15th exchange. A neighbour is
    # silent after 10 s of run (2 s of wall time at 5x), not the default 3 s: on a loaded
    # machine late maps would otherwise step the filters without measurements
    done = tcaff_main("team", "--scenario", "indoor_return", "--duration", "20", "--speed",
                      "5", "--ros2", "zenoh", "--domain-id", "3", "--bag", str(bag), "--output",
                      str(out), "--on-arrival", "--silence", "10")
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"ros2 bag play {bag}" in " ".join(done.stdout.split())
    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    for i, robot in enumerate(("r0", "r1")):
        rows = read_alignments(out / f"{robot}.csv")
        accepted = int((rows["accepted"] == 1).sum())
        # the node published its 20 maps and its accepted alignments on ROS 2 too
        counters = json.loads((out / f"{robot}.json").read_text())
        assert counters["ros2_sent"] == 20 + accepted and "ros2_errors" not in counters
        assert counts.get(ros2.alignment_topic(robot, f"r{1 - i}"), 0) == accepted
        assert counts[ros2.map_topic(robot)] == 20
        # exchanges are whole seconds; a map aligned on arrival is stamped after its exchange
        assert (rows["stamp"] != np.round(rows["stamp"])).any()
    assert sum(counts.get(ros2.alignment_topic(r, o), 0) for r, o in (("r0", "r1"),
                                                                      ("r1", "r0"))) > 0
    refused = tcaff_main("team", "--scenario", "indoor_return", "--bag", str(bag),
                         "--output", str(out))
    assert refused.returncode == 2 and "--bag" in refused.stderr


@pytest.mark.parametrize(("args", "words"), [
    (["--ros2-objects", "--scenario", "four_robots"], "no --scenario, --kimera or --replay"),
    (["--ros2-objects"], "--members None: --ros2-objects needs the team's robots"),
    (["--ros2-objects", "--members", "r0,r-1"], "ROS 2 name token"),
    (["--scenario", "four_robots", "--ros2", "zenoh", "--domain-id", "300"], "--domain-id 300"),
    (["--scenario", "four_robots", "--members", "r0,r1"], "only with --ros2-objects"),
    (["--ros2-objects", "--members", "r0,r1", "--speed", "2"], "--speed 2.0"),
])
def test_node_refuses_bad_ros2_options_in_one_line(tmp_path, tcaff_main, args, words):
    done = tcaff_main("node", "--robot", "r0", "--listen", f"127.0.0.1:{free_ports(1)[0]}",
                      "--output", str(tmp_path), *args)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and words in lines[0], done.stderr
