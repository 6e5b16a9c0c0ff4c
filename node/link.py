"""How a node reaches its team: Zenoh peer sessions with explicit endpoints, TCP or mutual TLS.

Keys of a team (names are letters, digits, `_` and `-`):
    tcaff/<team>/<robot>/map                    a robot's object map
    tcaff/<team>/<robot>/alignment/<neighbour>  its alignment T_oi_oj to a neighbour
    tcaff/<team>/<robot>/team/<other>           its team-consistent alignment to another robot
    tcaff/<team>/<robot>/alive                  liveliness token of its node
"""

from __future__ import annotations

import json
import logging
import re
import ssl
from dataclasses import dataclass, replace
from pathlib import Path

from tcaff_gtsam.errors import ConfigError, reason

__all__ = ["Link", "TlsFiles", "alignment_key", "alive_key", "check_name", "common_name",
           "identity_rules", "map_key", "team_key", "team_keys"]

log = logging.getLogger(__name__)

_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_ENDPOINT = re.compile(r"^[A-Za-z0-9_.-]+:\d{1,5}$")


def check_name(option: str, name: str) -> str:
    """`name` if it can be a team or robot name (a Zenoh key chunk); else ConfigError."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise ConfigError(f"{option} {name!r}: must be 1 to 64 letters, digits, '_' or '-'")
    return name


def map_key(team: str, robot: str) -> str:
    return f"tcaff/{team}/{robot}/map"


def alive_key(team: str, robot: str) -> str:
    """The liveliness token of a robot's node (held while its session is open)."""
    return f"tcaff/{team}/{robot}/alive"


def alignment_key(team: str, robot: str, neighbour: str) -> str:
    return f"tcaff/{team}/{robot}/alignment/{neighbour}"


def team_key(team: str, robot: str, other: str) -> str:
    """Where a robot publishes the team-consistent alignment T_oi_oj to another robot."""
    return f"tcaff/{team}/{robot}/team/{other}"


def team_keys(team: str) -> tuple[str, str]:
    """The key expressions of every map and every alignment of a team."""
    return f"tcaff/{team}/*/map", f"tcaff/{team}/*/alignment/*"


@dataclass(frozen=True)
class TlsFiles:
    """PEM files of a team's mutual TLS: the team's certificate authority, and this node's
    certificate (signed by it, naming the host it listens on) and private key."""

    ca: Path
    certificate: Path
    key: Path

    def __post_init__(self) -> None:
        for name in ("ca", "certificate", "key"):
            path = Path(getattr(self, name))
            if not path.is_file():
                raise ConfigError(f"--tls-{name.replace('certificate', 'cert')} {str(path)!r}: "
                                  f"no such file")
            object.__setattr__(self, name, path)
        # read now, as Zenoh reads them only when a link opens (a listener with garbage files
        # used to run unlinked and exit 0)
        try:
            ssl.create_default_context(cafile=str(self.ca)).load_cert_chain(
                str(self.certificate), str(self.key))
        except (ssl.SSLError, OSError, ValueError) as exc:
            raise ConfigError(f"--tls-ca/--tls-cert/--tls-key {str(self.ca)!r}, "
                              f"{str(self.certificate)!r}, {str(self.key)!r}: not a PEM "
                              f"certificate authority, certificate and its key ({exc})") from None


def common_name(certificate: Path) -> str | None:
    """The common name of a PEM certificate's subject (None: it has none).

    Raises:
        ConfigError: the file is not a PEM certificate.
    """
    try:
        # the standard library's only certificate reader (CPython's, since 2.7): no third
        # party X.509 package for one field
        subject = ssl._ssl._test_decode_cert(str(certificate))["subject"]
    except (ssl.SSLError, OSError, KeyError) as exc:
        raise ConfigError(f"--tls-cert {str(certificate)!r}: not a PEM certificate ({exc})"
                          ) from None
    names = [value for rdn in subject for key, value in rdn if key == "commonName"]
    return names[-1] if names else None


@dataclass(frozen=True)
class Link:
    """A node's Zenoh endpoints: where it listens and which peers it dials.

    Attributes:
        listen: "host:port" endpoints this node accepts peers on (may be empty).
        connect: "host:port" endpoints of peers it dials (it retries until they are up).
        tls: the team's certificates; None: plain TCP. With TLS every link is mutual TLS and
            a peer without a certificate of the team's authority is refused.
        identities: with TLS, each robot's certificate names its robot (its common name is
            the robot's name): a node takes a message on `tcaff/<team>/<robot>/...` (and on
            the robot's ROS 2 topics) only from the certificate of that robot, so a holder of
            another robot's certificate cannot speak for it. Zenoh's access control refuses
            the others at the link, before the node sees them (Zenoh logs them; the node
            cannot count them). None (the default): decided by the node's certificate
            (`for_robot`): checked when it names the node's robot, else not, with a warning
            that any holder of the team's certificate can speak for any robot.
    """

    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    tls: TlsFiles | None = None
    identities: bool | None = None

    def __post_init__(self) -> None:
        for option, endpoints in (("--listen", self.listen), ("--connect", self.connect)):
            for endpoint in endpoints:
                if not _ENDPOINT.match(endpoint) or not 0 < int(endpoint.rsplit(":")[1]) < 65536:
                    raise ConfigError(f"{option} {endpoint!r}: must be host:port, port in "
                                      f"1..65535")
        if not self.listen and not self.connect:
            raise ConfigError("a node needs --listen or --connect endpoints (or both)")
        if self.identities and self.tls is None:
            raise ConfigError("--tls-identities needs the team's certificates (--tls-ca, "
                              "--tls-cert, --tls-key)")
        if self.identities not in (None, True, False):
            raise ConfigError(f"Link identities {self.identities!r}: must be True, False or "
                              f"None")

    def for_robot(self, robot: str) -> Link:
        """This link as `robot`'s node runs it: `identities` None becomes True when the
        certificate's common name is `robot` and False (warned: any holder of the team's
        certificate can speak for any robot) when it is not; without TLS, False."""
        if self.identities is not None:
            return self
        named = self.tls is not None and common_name(self.tls.certificate) == robot
        if self.tls is not None and not named:
            warn_shared_certificate(self.tls.certificate, robot)
        return replace(self, identities=named)

    def config(self, team: str | None = None, robots: tuple[str, ...] = ()):
        """The zenoh.Config of a peer with exactly these endpoints, multicast scouting off;
        with `identities`, the access control of `team`'s `robots` (see `identity_rules`)."""
        import zenoh

        protocol = "tcp" if self.tls is None else "tls"
        config = zenoh.Config()
        config.insert_json5("mode", '"peer"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("listen/endpoints",
                            json.dumps([f"{protocol}/{e}" for e in self.listen]))
        config.insert_json5("connect/endpoints",
                            json.dumps([f"{protocol}/{e}" for e in self.connect]))
        # a peer that is not up yet is dialled again soon (Zenoh's default backs off to 4 s)
        config.insert_json5("connect/retry", "{period_init_ms: 100, period_max_ms: 1000, "
                                             "period_increase_factor: 1.5}")
        if self.tls is not None:
            tls = self.tls
            files = {"root_ca_certificate": tls.ca, "listen_certificate": tls.certificate,
                     "listen_private_key": tls.key, "connect_certificate": tls.certificate,
                     "connect_private_key": tls.key}
            for name, path in files.items():
                config.insert_json5(f"transport/link/tls/{name}", json.dumps(str(path)))
            config.insert_json5("transport/link/tls/enable_mtls", "true")
        if self.identities and team is not None:
            config.insert_json5("access_control", json.dumps(identity_rules(team, robots)))
        return config

    def open(self, team: str | None = None, robots: tuple[str, ...] = ()):
        """An open zenoh.Session (with `identities`, of `team`'s `robots`).

        Raises:
            ConfigError: Zenoh cannot open it (a --listen port in use, a host it cannot
                resolve), naming the endpoints.
        """
        import zenoh

        config = self.config(team, robots)
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            raise ConfigError(f"--listen {list(self.listen)} / --connect "
                              f"{list(self.connect)}: Zenoh cannot open the session "
                              f"({reason(exc)})") from None


def warn_shared_certificate(certificate: Path, robot: str) -> None:
    """Say that a certificate that does not name `robot` lets any holder speak for any
    robot."""
    log.warning("%s: the certificate %s names %r, not the robot: robots' identities are not "
                "checked, any holder of the team's certificate can speak for any robot (give "
                "each robot a certificate whose common name is its name)", robot,
                certificate, common_name(certificate))


def identity_rules(team: str, robots: tuple[str, ...]) -> dict:
    """Zenoh access control (its `access_control` configuration) by which a session takes a
    put or delete on `tcaff/<team>/<robot>/**` or on the robot's ROS 2 topics
    (`<domain>/<robot>/tcaff/**`) only from a peer whose certificate's common name is that
    robot; everything else (subscribing, liveliness, queries, its own puts) is allowed to
    the certificates that name a robot of `robots`, and nothing to others (a certificate of
    the team's authority that names no robot links, but is refused every message)."""
    not_puts = ["declare_subscriber", "query", "declare_queryable", "reply",
                  "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]
    rules = [{"id": "declarations", "permission": "allow", "flows": ["ingress", "egress"],
              "messages": not_puts, "key_exprs": ["**", "@ros2_lv/**"]},
             {"id": "own puts", "permission": "allow", "flows": ["egress"],
              "messages": ["put", "delete"], "key_exprs": ["**"]}]
    subjects = [{"id": "team", "cert_common_names": list(robots)}]
    policies = [{"rules": ["declarations", "own puts"], "subjects": ["team"]}]
    for robot in robots:
        rules.append({"id": f"puts of {robot}", "permission": "allow", "flows": ["ingress"],
                      "messages": ["put", "delete"],
                      "key_exprs": [f"tcaff/{team}/{robot}/**", f"*/{robot}/tcaff/**"]})
        subjects.append({"id": f"is {robot}", "cert_common_names": [robot]})
        policies.append({"rules": [f"puts of {robot}"], "subjects": [f"is {robot}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}
