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
