"""Who may join: with the team's certificates every link is mutual TLS, and a process without
a certificate of the team's authority (another authority's, or none) receives nothing."""

from __future__ import annotations

import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from tcaff_gtsam.node import Link, RobotNode, TlsFiles
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


_LISTENER = """
import sys, time
from pathlib import Path
from tcaff_gtsam.node.link import Link, TlsFiles
port, files = sys.argv[1], sys.argv[2:]
tls = TlsFiles(*map(Path, files)) if files else None
received = []
with Link(connect=(f"127.0.0.1:{port}",), tls=tls).open() as session:
    session.declare_subscriber("tcaff/tls/*/map", received.append)
    time.sleep(4.0)
print(len(received))
"""


def test_only_holders_of_the_teams_certificate_receive_its_maps(tmp_path: Path) -> None:
    team = make_authority(tmp_path / "team", "team")
    rogue = make_authority(tmp_path / "rogue", "rogue")
    port = free_ports(1)[0]
    node = RobotNode("r0", "tls", ["r0", "r1"], Link(listen=(f"127.0.0.1:{port}",), tls=team))
    stop = threading.Event()

    def publish() -> None:
        t = 0.0
        while not stop.wait(0.1):
            t += 0.1
            node.publish(t, ObjectMap(np.zeros((3, 3)), np.ones(3), np.ones(3), np.full(3, t)))

    sender = threading.Thread(target=publish)
    sender.start()
    try:
        listeners = {
            name: subprocess.Popen([sys.executable, "-c", _LISTENER, str(port),
                                    *(map(str, (files.ca, files.certificate, files.key))
                                      if files else ())],
                                   stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            for name, files in (("team", team), ("rogue", rogue), ("plain", None))}
        received = {name: int(p.communicate(timeout=60)[0].split()[-1])
                    for name, p in listeners.items()}
    finally:
        stop.set()
        sender.join()
        node.close()
    assert received["team"] > 5
    assert received["rogue"] == 0 and received["plain"] == 0


def test_missing_certificate_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"--tls-ca .*no such file"):
        TlsFiles(tmp_path / "ca.pem", tmp_path / "node.pem", tmp_path / "node.key")


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


@pytest.mark.parametrize("identities", [True, False])
def test_a_team_certificate_of_r3_cannot_publish_r1s_map(tmp_path: Path, identities) -> None:
    """With identities, r0 takes r1's map only from r1's certificate: r3's certificate, of the
    same authority, cannot speak for r1 (without them it can: the control)."""
    import time

    from tcaff_gtsam.node import MapMessage, encode

    certs = robot_certificates(tmp_path / "certs", ["r0", "r1", "r3", "stranger"])
    port = free_ports(1)[0]
    node = RobotNode("r0", "ids", ["r0", "r1", "r3"],
                     Link(listen=(f"127.0.0.1:{port}",), tls=certs["r0"],
                          identities=identities))
    received = {}
    try:
        node.publish(1.0, ObjectMap(np.zeros((3, 3)), np.ones(3), np.ones(3), np.ones(3)))
        for holder in ("r3", "stranger", "r1"):  # each speaking for r1
            before = node.counters["maps_received"]
            with Link(connect=(f"127.0.0.1:{port}",), tls=certs[holder]).open() as session:
                time.sleep(1.0)  # linked
                session.put("tcaff/ids/r1/map", encode(MapMessage(
                    "r1", 1, len(received), 1.0, np.zeros((3, 3)), np.ones(3), np.ones(3),
                    np.zeros(3))))
                time.sleep(1.0)
            node.wait_idle()
            received[holder] = node.counters["maps_received"] - before
    finally:
        node.close()
    assert received["r1"] == 1
    assert received["r3"] == received["stranger"] == (0 if identities else 1)


def test_identities_need_the_teams_certificates() -> None:
    with pytest.raises(ConfigError, match="--tls-identities needs"):
        Link(listen=("127.0.0.1:7447",), identities=True)
