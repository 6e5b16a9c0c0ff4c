"""A team replaying Kimera-Multi bags: `tcaff team --kimera` maps each robot's bag through the
RGB-D front end once, then one node process per robot replays the maps over Zenoh on
127.0.0.1. The bags are small ones written from the rendered simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tcaff_gtsam.eval.config import MethodsConfig, load_kimera_multi
from tcaff_gtsam.eval.datasets import kimera_multi
from tcaff_gtsam.eval.methods import run_methods
from tcaff_gtsam.node.results import read_alignments

ROBOTS = ("acl_jackal2", "sparkal2")  # the robots of the shipped test same_direction


@pytest.fixture(scope="module")
def bags(kimera_like_sequence) -> Path:
    """30 s of two robots at 240 x 180, 5 Hz (TCAFF accepts from about 17 s on)."""
    return kimera_like_sequence[0]


def test_a_team_replays_the_robots_of_kimera_bags(bags: Path, tmp_path: Path,
                                                  tcaff_main) -> None:
    """Each node aligns at every exchange the robots share, as the offline study does on the
    same maps; a node asked for a robot the bags do not have is refused in one line."""
    out = tmp_path / "team"
    # the nodes align in lockstep (exchange k with exchange k), so the speed-up changes the
    # wall time only, not what is aligned
    done = tcaff_main("team", "--kimera", str(bags), "--speed", "8", "--output", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    assert "r0 (acl_jackal2), r1 (sparkal2)" in done.stdout
    for robot in ROBOTS:
        assert (out / "maps" / f"{robot}.npz").is_file()
    # the maps the team made, read back (reused, not mapped again)
    run, _, reused = kimera_multi.load_run(load_kimera_multi("same_direction"), bags,
                                           out / "maps")
    assert reused == list(ROBOTS)
    assert all(sum(len(m) for m in maps) > 0 for maps in run.maps)
    offline = run_methods(run, MethodsConfig(methods=["tcaff"]))
    S = len(run.times)
    for i in range(2):
        rows = read_alignments(out / f"r{i}.csv")
        assert rows["seq"].astype(int).tolist() == list(range(S))
        x = np.column_stack([rows[c] for c in ("x", "y", "theta")])
        expected = offline.estimates["tcaff"][offline.pairs.index((i, 1 - i))]
        np.testing.assert_array_equal(rows["accepted"] == 1, np.isfinite(expected[:, 0]))
        assert (rows["accepted"] == 1).sum() >= 5  # estimates compared, not only refusals
        np.testing.assert_allclose(x[rows["accepted"] == 1],
                                   expected[np.isfinite(expected[:, 0])], atol=1e-4)
    # a node of the same bags (their maps reused) for a robot they do not have
    refused = tcaff_main("node", "--robot", "r5", "--kimera", str(bags), "--listen",
                         "127.0.0.1:7447", "--output", str(out))
    assert refused.returncode == 2
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and "r0 (acl_jackal2), r1 (sparkal2)" in lines[0], refused.stderr
