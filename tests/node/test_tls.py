"""Who may join: with the team's certificates every link is mutual TLS, and a session without
a certificate of the team's authority (another authority's, or none) receives nothing."""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from tcaff_gtsam.node import Link, MapMessage, RobotNode, TlsFiles, encode
from tcaff_gtsam.node.run import free_ports

from tcaff_gtsam import ObjectMap
from tcaff_gtsam.errors import ConfigError

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl")


def make_authority(folder: Path, name: str) -> TlsFiles:
    """A certificate authority `name` and a certificate it signs for 127.0.0.1."""
    folder.mkdir(parents=True)

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=folder, check=True, capture_output=True)

    openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
            "-keyout", "ca.key", "-out", "ca.pem", "-days", "2", "-subj", f"/CN={name} CA")
    openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
            "-keyout", "node.key", "-out", "node.csr", "-subj", f"/CN={name} node")
    (folder / "san.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    openssl("x509", "-req", "-in", "node.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
            "-CAcreateserial", "-out", "node.pem", "-days", "2", "-extfile", "san.ext")
    return TlsFiles(folder / "ca.pem", folder / "node.pem", folder / "node.key")


def robot_certificates(folder: Path, robots: list[str]) -> dict[str, TlsFiles]:
    """One team authority and a certificate per robot whose common name is the robot."""
    folder.mkdir(parents=True)

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=folder, check=True, capture_output=True)

    openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
            "-keyout", "ca.key", "-out", "ca.pem", "-days", "2", "-subj", "/CN=team CA")
    (folder / "san.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    out = {}
    for robot in robots:
        openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
                "-keyout", f"{robot}.key", "-out", f"{robot}.csr", "-subj", f"/CN={robot}")
        openssl("x509", "-req", "-in", f"{robot}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
                "-CAcreateserial", "-out", f"{robot}.pem", "-days", "2", "-extfile", "san.ext")
        out[robot] = TlsFiles(folder / "ca.pem", folder / f"{robot}.pem", folder / f"{robot}.key")
    return out


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> dict[str, TlsFiles]:
    """The team authority's certificates of r0, r1, r3 and of "stranger" (a name of no
    robot), and "rogue": another authority's; made once, as no test changes them."""
    folder = tmp_path_factory.mktemp("certs")
    return robot_certificates(folder / "team", ["r0", "r1", "r3", "stranger"]) | {
        "rogue": make_authority(folder / "rogue", "rogue")}


def wait_for(condition, timeout: float) -> None:
    """Until `condition()` holds; `timeout` s at most (the assertions after tell)."""
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)


def test_only_holders_of_the_teams_certificate_receive_its_maps(certs) -> None:
    port = free_ports(1)[0]
    node = RobotNode("r0", "tls", ["r0", "r1"], Link(listen=(f"127.0.0.1:{port}",),
                                                      tls=certs["r0"]))
    stop = threading.Event()

    def publish() -> None:
        t = 0.0
        while not stop.wait(0.1):
            t += 0.1
            node.publish(t, ObjectMap(np.zeros((3, 3)), np.ones(3), np.ones(3), np.full(3, t)))

    sender = threading.Thread(target=publish)
    sender.start()
    listeners = {"team": certs["r1"], "rogue": certs["rogue"], "plain": None}
    received: dict[str, list] = {name: [] for name in listeners}
    sessions = []
    try:
        # opened side by side: a session that cannot link tries for half a second first
        with ThreadPoolExecutor(len(listeners)) as pool:
            sessions = list(pool.map(
                lambda files: Link(connect=(f"127.0.0.1:{port}",), tls=files).open(),
                listeners.values()))
        for name, session in zip(listeners, sessions, strict=True):
            session.declare_subscriber("tcaff/tls/*/map", received[name].append)
        # every listener is up (the rogue and plain ones dialling again every second at
        # most) while the team's listener is sent ten maps, a second of the node's
        first = len(received["team"])
        wait_for(lambda: len(received["team"]) >= first + 10, 60)
    finally:
        for session in sessions:
            session.close()
        stop.set()
        sender.join()
        node.close()
    assert len(received["team"]) > 5
    assert len(received["rogue"]) == 0 and len(received["plain"]) == 0


def test_missing_certificate_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"--tls-ca .*no such file"):
        TlsFiles(tmp_path / "ca.pem", tmp_path / "node.pem", tmp_path / "node.key")


def test_files_that_are_not_the_certificates_are_refused_when_given(certs, tmp_path) -> None:
    """Zenoh reads them only when a link opens: a listener given garbage ran unlinked."""
    garbage = tmp_path / "garbage.pem"
    garbage.write_text("not a pem")
    r0, r1 = certs["r0"], certs["r1"]
    for files in ((garbage, r0.certificate, r0.key), (r0.ca, garbage, r0.key),
                  (r0.ca, r0.certificate, garbage),
                  (r0.ca, r0.certificate, r1.key)):  # a key of another certificate
        with pytest.raises(ConfigError, match="not a PEM certificate authority, certificate "
                                              "and its key"):
            TlsFiles(*files)
    TlsFiles(r0.ca, r0.certificate, r0.key)


@pytest.mark.parametrize("identities", [True, None, False])
def test_a_team_certificate_of_r3_cannot_publish_r1s_map(certs, identities) -> None:
    """With identities, r0 takes r1's map only from r1's certificate: r3's certificate, of the
    same authority, cannot speak for r1 (without them it can: the control). By default
    (None) they are checked, as r0's certificate names r0."""
    holders = ("r3", "stranger", "r1")  # each speaking for r1
    # a node r0 per holder, side by side: a node that has a newer map of r1 waiting skips
    # the older, so that one node would take one of maps arriving together
    ports = dict(zip(holders, free_ports(len(holders)), strict=True))
    nodes, sessions = {}, []
    try:
        for holder, port in ports.items():
            nodes[holder] = RobotNode("r0", "ids", ["r0", "r1", "r3"],
                                      Link(listen=(f"127.0.0.1:{port}",), tls=certs["r0"],
                                           identities=identities))
            nodes[holder].publish(1.0, ObjectMap(np.zeros((3, 3)), np.ones(3), np.ones(3),
                                                 np.ones(3)))
        # a session opens linked, at times half a second after it dials: side by side
        with ThreadPoolExecutor(len(holders)) as pool:
            sessions = list(pool.map(
                lambda h: Link(connect=(f"127.0.0.1:{ports[h]}",), tls=certs[h]).open(),
                holders))
        publishers = [s.declare_publisher("tcaff/ids/r1/map") for s in sessions]
        # each node's subscription reaches the sessions it is declared to (with identities,
        # not the stranger's): a second at most
        wait_for(lambda: all(p.matching_status.matching for p in publishers), 1.0)
        for publisher in publishers:
            publisher.put(encode(MapMessage("r1", 1, 0, 1.0, np.zeros((3, 3)), np.ones(3),
                                            np.ones(3), np.zeros(3))))
        sent = time.monotonic()

        def taken(holder: str) -> bool:
            return nodes[holder].counters["maps_received"] > 0

        # every map taken, or r1's own taken and a second more for the others'
        wait_for(lambda: all(map(taken, holders)) or (
            taken("r1") and time.monotonic() > sent + 1.0), 20)
        for node in nodes.values():
            node.wait_idle()
    finally:
        for session in sessions:
            session.close()
        for node in nodes.values():
            node.close()
    received = {holder: node.counters["maps_received"] for holder, node in nodes.items()}
    assert received["r1"] == 1
    assert received["r3"] == received["stranger"] == (1 if identities is False else 0)


def test_identities_are_checked_when_the_certificate_names_its_robot(certs, caplog) -> None:
    """Secure by default: a node whose certificate names its robot checks identities without
    being asked; one whose certificate names another (a certificate shared by the team) does
    not, and says that any holder can speak for any robot; asked for, they are checked."""
    link = Link(listen=("127.0.0.1:7447",), tls=certs["r0"])
    with caplog.at_level("WARNING", logger="tcaff_gtsam.node.link"):
        assert link.for_robot("r0").identities is True
        assert not caplog.records
        assert link.for_robot("r1").identities is False
    assert "any holder of the team's certificate can speak for any robot" in caplog.text
    assert "names 'r0'" in caplog.text
    forced = Link(listen=("127.0.0.1:7447",), tls=certs["stranger"], identities=True)
    assert forced.for_robot("r0").identities is True
    assert Link(listen=("127.0.0.1:7447",)).for_robot("r0").identities is False


def test_identities_need_the_teams_certificates() -> None:
    with pytest.raises(ConfigError, match="--tls-identities needs"):
        Link(listen=("127.0.0.1:7447",), identities=True)
