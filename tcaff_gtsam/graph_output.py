"""What `InterRobotGraph` reads out: an alignment T_oi_oj with its marginal covariance, whether
two robots are linked, the history of an alignment, and the graph in g2o format."""

from __future__ import annotations

from bisect import bisect_left
from pathlib import Path

import gtsam
import numpy as np

from .errors import DataError, reason
from .graph_inputs import _components, alignment_key
from .inputs import output_path

__all__ = ["GraphReadout"]


class GraphReadout:
    """The part of `InterRobotGraph` that reads alignments out of the solution and writes it
    (mixed into it; it uses the graph's own attributes)."""

    def alignment(self, i: int, j: int, step: int | None = None, covariance: bool = True
                  ) -> tuple[np.ndarray, np.ndarray | None]:
        """T_oi_oj(step) = A_i(step)^-1 A_j(step) from the current solution.

        Returns:
            T: (3, 3) or (4, 4); cov: covariance of (x, y, theta) / (x, y, z, yaw), or None
            when `covariance` is False. For the latest step, its marginal covariance. For an
            earlier step, with `GraphParams.past_covariance = "causal"` (the default), the
            marginal it had while it was the latest, unless a factor it counted (of its step
            or an earlier one) has been removed for good since (then, and with "smoothed", its
            marginal now); a step that left the horizon keeps the one it left with. Robots that
            no alignment factor links (`connected` false now, or, for a covariance kept from
            when the step was the latest, then): T is arbitrary and the covariance infinite on
            its diagonal.
        Raises:
            DataError: unknown robot, a step that has not been committed, or one forgotten
                (`GraphParams.history`); a covariance gtsam cannot compute (a graph of
                near-singular covariances).
        """
        self._check_robot("i", i)
        self._check_robot("j", j)
        if not self._steps:
            raise DataError("alignment: no step has been committed yet")
        step = self._steps[-1] if step is None else step
        if step not in self._step_set:
            raise DataError(f"alignment: step {step} has not been committed")
        if bisect_left(self._steps, step) < self._n_forgotten:
            raise DataError(f"alignment: step {step} left the horizon and was forgotten "
                            f"(GraphParams.history = {self.params.history}: only that many of "
                            f"the latest steps that left are kept)")
        ki, kj = alignment_key(i, step), alignment_key(j, step)
        A_i, A_j = self._value(ki), self._value(kj)
        T = np.linalg.inv(A_i) @ A_j
        if not covariance:
            return T, None
        if i == j:
            return T, np.zeros((self._n_param, self._n_param))
        # robots no alignment links (now, or when the step's kept joint was computed: NaN
        # between them, `_joint`) are held by the gauge priors alone: T is arbitrary, and the
        # priors' 1 m and 1 rad would be taken for an uncertainty by whoever weighs it
        unknown = T, np.diag(np.full(self._n_param, np.inf))
        try:
            every = self._kept_joint(step)
            if every is None:
                if not self.connected(i, j):
                    return unknown
                joint = self._isam.jointMarginalCovariance(
                    gtsam.KeyVector([ki, kj])).fullMatrix()
        except RuntimeError as exc:  # the graph stays as it is: its estimates can be read
            raise DataError(f"alignment: gtsam could not compute the covariance of step "
                            f"{step} ({reason(exc)}); read the alignment with "
                            f"covariance=False") from None
        if every is not None:
            n = 3 if self._planar else 6
            rows = np.r_[i * n:(i + 1) * n, j * n:(j + 1) * n]
            joint = every[np.ix_(rows, rows)]
            if np.isnan(joint).any():
                return unknown
        Ad_inv = self._pose(np.linalg.inv(T)).AdjointMap()
        J = np.hstack([-Ad_inv, np.eye(Ad_inv.shape[0])])
        return T, self._params_cov(T, J @ joint @ J.T)

    def connected(self, i: int, j: int) -> bool:
        """Whether committed factors link robots i and j: alignments, directly or through other
        robots or their keyframe chains. When they do not, `alignment(i, j)` is only the
        gauge's guess: its value is arbitrary and its covariance infinite."""
        self._check_robot("i", i)
        self._check_robot("j", j)
        linked = self._linked()
        return linked[i] == linked[j]

    def _linked(self, committing=()) -> np.ndarray:
        """(n_robots,) int: robots of one number are linked by committed factors (and by the
        factors `committing`, which an update is committing): alignments, directly or through
        other robots or the keyframe chains (robot 0's alignment and keyframe chains, both
        anchored, count as one)."""
        chains = self._a_chains | {("X", robot) for robot in self._last_keyframe}
        links = [link for link, n in self._links.items() if n > 0]
        links += [q.link for q in committing if q.link] + [(("A", 0), ("X", 0))]
        root = _components(chains, links)
        number: dict = {}
        return np.array([number.setdefault(root(("A", r)), len(number))
                         for r in range(self.n_robots)])

    def alignment_history(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """T_oi_oj at every committed step from the current (smoothed) solution, except the
        steps forgotten (`GraphParams.history`).

        Returns:
            steps (n,) and T (n, 3, 3) / (n, 4, 4).
        """
        self._check_robot("i", i)
        self._check_robot("j", j)
        estimate = self._isam.calculateEstimate()
        get = estimate.atPose2 if self._planar else estimate.atPose3

        def A(robot: int, k: int) -> np.ndarray:
            return self._left[k][0][robot] if k in self._left else get(
                alignment_key(robot, k)).matrix()

        steps = self._steps[self._n_forgotten:]
        T = np.array([np.linalg.inv(A(i, k)) @ A(j, k) for k in steps])
        size = self._side
        return np.array(steps, np.int64), T.reshape(-1, size, size)

    def alignment_params(self, i: int, j: int, step: int | None = None) -> np.ndarray:
        """(x, y, theta) or (x, y, z, yaw) of T_oi_oj(step), without covariance."""
        return self._params(self.alignment(i, j, step, covariance=False)[0])

    def write_g2o(self, path: str | Path) -> None:
        """Write the active factors and the current solution in g2o format (with a horizon:
        the factors and variables still in the graph).

        Raises:
            DataError: the folder is missing, the path is a folder, or the file could not be
                written.
        """
        path = output_path("write_g2o", path)
        graph = gtsam.NonlinearFactorGraph()
        for index in sorted(self._active):
            factor = self._active[index].factor
            if isinstance(factor, (gtsam.BetweenFactorPose2, gtsam.BetweenFactorPose3)):
                noise = factor.noiseModel()
                if isinstance(noise, gtsam.noiseModel.Robust):
                    # g2o edges carry an information matrix; the M-estimator is not exported
                    factor = type(factor)(*factor.keys(), factor.measured(), noise.noise())
            graph.add(factor)
        try:
            path.unlink(missing_ok=True)  # so a failed write cannot leave an old file behind
        except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the name
            raise DataError(f"write_g2o: cannot replace {path} ({exc})") from None
        gtsam.writeG2o(graph, self._isam.calculateEstimate(), str(path))
        if not path.is_file():  # gtsam reports nothing when it cannot open the file
            raise DataError(f"write_g2o: {path} could not be written")
