"""What the team consistency takes: the judge the node's message checks are held to."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from tcaff_gtsam.node.messages import AlignmentMessage

from tcaff_gtsam import TeamConsistency
from tcaff_gtsam.errors import DataError

#: numbers of an estimate, the edges of what the team consistency takes among them
edgy = st.one_of(st.floats(-10, 10), st.floats(allow_nan=True, allow_infinity=True),
                 st.sampled_from([0.0, -0.0, 1e-300, 1e9, -1e9, 1.0000001e9, -1.0000001e9,
                                  1e18, -1e18, 1.0000001e18, -1.0000001e18]))


def team_takes(x: np.ndarray, P: np.ndarray) -> bool:
    """Whether TeamConsistency.update takes the estimate (x, P) of pair (0, 1)."""
    estimate = AlignmentMessage("r0", 0, 0, 5.0, "r1", 0, np.nan, 0, 0, True, x, P)
    try:
        TeamConsistency(3).update({(0, 1): estimate})
    except DataError:
        return False
    return True
