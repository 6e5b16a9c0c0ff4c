"""Keyframes in `InterRobotGraph`, for CSLAM use: each robot's keyframe poses X_r(m) chained by
its odometry, inter-robot factors between keyframes from accepted alignments, and any other
between-factor a user has (loop closures)."""

from __future__ import annotations

import numpy as np

from .errors import DataError
from .graph_inputs import (
    _ROBOT_SHIFT,
    _chain,
    _check_cov,
    _check_index,
    _keyframe_of,
    _step_of,
    _x_key,
    alignment_key,
    keyframe_key,
)
from .inputs import shown
from .params import _int_at_least

__all__ = ["KeyframeFactors"]


class KeyframeFactors:
    """The part of `InterRobotGraph` that takes keyframes (mixed into it; it uses the graph's
    own attributes)."""

    def add_keyframe(self, robot: int, index: int, T_o_b, odometry_cov=None) -> None:
        """Queue keyframe X_robot(index) at odometry pose T_o_b (body in robot's odometry frame).

        The first keyframe of robot 0 is anchored at T_o_b; other robots' first keyframes get
        the weak prior, placed through the current alignment estimate when there is one. Later
        keyframes are linked to the previous one by the odometry between them.

        With `GraphParams.horizon`, a keyframe leaves the graph with the step of the first
        `update(step)` after it was added, except a robot's latest: it stays until the next
        is added, so that the odometry between them has both to act on.

        Args:
            T_o_b: (3, 3) SE(2) or (4, 4) SE(3) matrix.
            odometry_cov: covariance of the odometry from the previous keyframe in gtsam's
                tangent order, (3, 3) or (6, 6); `GraphParams.odometry_cov` when None.
        Raises:
            DataError: unknown robot, index not increasing, non-finite pose.
        """
        self._check_robot("robot", robot)
        T = self._rigid("add_keyframe: T_o_b", T_o_b)
        key = keyframe_key(robot, index)
        last = self._last_keyframe.get(robot)
        if last is not None and index <= last:
            raise DataError(f"add_keyframe: robot {robot} index {index} is not after {last}")
        frames = self._keyframes[robot]
        if last is None:
            if robot == 0:  # robot 0's odometry frame is the common frame
                self._insert(key, T)
                self._queue_prior(key, T, (self.params.anchor_sigma,) * 2)
            else:
                A = (self._value(alignment_key(robot, self._steps[-1])) if self._steps
                     else np.eye(T.shape[0]))
                self._insert(key, A @ T)
        else:
            delta = np.linalg.inv(frames[last]) @ T
            cov = (self.params.odometry_cov if odometry_cov is None
                   else _check_cov("add_keyframe: odometry_cov", odometry_cov,
                                   3 if self._planar else 6))
            prev_key = keyframe_key(robot, last)
            self._insert(key, self._value(prev_key) @ delta)
            self._queue_between(prev_key, key, delta, self._noise(cov, False))
        frames[index] = T
        self._last_keyframe[robot] = index
        rank = len(self._steps)  # the step the next update adds
        self._keyframe_rank[key] = rank
        self._keyframes_at[rank].append(key)

    def _keyframe(self, name: str, robot, index) -> int:
        """The index of a keyframe in the graph, else DataError."""
        self._check_robot("robot", robot)
        index = _check_index(f"{name}: keyframe index", index, _ROBOT_SHIFT)
        if index in self._left_keyframes[robot]:
            raise DataError(f"{name}: keyframe {index} of robot {robot} has left the graph "
                            f"(horizon {self.params.horizon} steps, latest {self._steps[-1]})")
        if index not in self._keyframes[robot]:
            forgotten = self._forgotten_keyframe.get(robot)
            if forgotten is not None and index <= forgotten:
                raise DataError(f"{name}: robot {robot} has no keyframe {index} in the graph: "
                                f"its keyframes up to {forgotten} left it and were forgotten "
                                f"(GraphParams.history = {self.params.history})")
            raise DataError(f"{name}: robot {robot} has no keyframe {index}")
        return index

    def add_keyframe_alignment(self, i: int, m_i: int, j: int, m_j: int, T_oi_oj, cov,
                               hypothesis: int | None = None) -> None:
        """Queue an inter-robot factor between keyframes X_i(m_i) and X_j(m_j) from an alignment
        T_oi_oj: X_i^-1 X_j = T_oi_bi^-1 T_oi_oj T_oj_bj.

        Raises:
            DataError: unknown robot or keyframe, a keyframe that left the graph, bad values.
        """
        m_i = self._keyframe("add_keyframe_alignment", i, m_i)
        m_j = self._keyframe("add_keyframe_alignment", j, m_j)
        T = self._matrix(T_oi_oj)
        C = self._tangent_cov(T, _check_cov("add_keyframe_alignment: cov", cov, self._n_param))
        T_oj_bj = self._keyframes[j][m_j]
        T_bi_bj = np.linalg.inv(self._keyframes[i][m_i]) @ T @ T_oj_bj
        Ad = self._pose(np.linalg.inv(T_oj_bj)).AdjointMap()
        noise = self._noise(Ad @ C @ Ad.T, True)
        i, j = int(i), int(j)
        self._queue_between(_x_key(i, m_i), _x_key(j, m_j), T_bi_bj, noise,
                            ("keyframe", i, j, hypothesis), link=(("X", i), ("X", j)))

    def add_between(self, key_a: int, key_b: int, T_a_b, cov_tangent, robust: bool = True
                    ) -> None:
        """Queue any between-factor on existing keys (a user's own loop closure, say).

        Args:
            key_a, key_b: keys from `keyframe_key` / `alignment_key`.
            T_a_b: relative pose matrix; cov_tangent: its covariance in gtsam's tangent order.
        """
        if not isinstance(robust, (bool, np.bool_)):
            raise DataError(f"add_between: robust must be True or False, got {shown(robust)}")
        T = self._rigid("add_between: T_a_b", T_a_b)
        C = _check_cov("add_between: cov_tangent", cov_tangent, 3 if self._planar else 6)
        for name, key in (("key_a", key_a), ("key_b", key_b)):
            if not _int_at_least(key, 0) or key >= 1 << 64:
                raise DataError(f"add_between: {name} = {key!r} is not a gtsam key (an int "
                                f"from keyframe_key or alignment_key)")
        if key_a == key_b:
            raise DataError("add_between: key_a and key_b are the same variable")
        for key in (key_a, key_b):
            if not self._exists(key):
                step = _step_of(key)
                robot, index = _keyframe_of(key)
                left = robot < self.n_robots and self._has_left(key)
                name = (f"A_{robot}({step})" if step is not None else f"X_{robot}({index})")
                raise DataError(f"add_between: {name} = key {key} "
                                f"{'has left the graph' if left else 'does not exist'}")
        link = (_chain(key_a), _chain(key_b))
        self._queue_between(key_a, key_b, T, self._noise(C, robust),
                            link=link if link[0] != link[1] else None)

    def trajectory(self, robot: int) -> tuple[np.ndarray, np.ndarray]:
        """Committed keyframes of `robot`: indices (m,) and poses (m, 3, 3) / (m, 4, 4) in the
        common frame. Keyframes that left the graph (with a horizon) keep the pose they had
        when they left, until they are forgotten (`GraphParams.history`)."""
        self._check_robot("robot", robot)
        estimate = self._isam.calculateEstimate()
        get = estimate.atPose2 if self._planar else estimate.atPose3
        left = self._left_keyframes[robot]
        inside = [i for i in self._keyframes[robot] if estimate.exists(keyframe_key(robot, i))]
        poses = [*left.values(), *(get(keyframe_key(robot, i)).matrix() for i in inside)]
        size = self._side
        return (np.array([*left, *inside], np.int64),
                np.array(poses, dtype=float).reshape(-1, size, size))
