"""ObjectIdentities: the same object under the same id from one map exchange to the next.

A robot's shared map need not keep an object at the same index (a windowed map, say, rebuilds
its list at every exchange). TCAFF counts evidence by the objects a measurement associates, so
it needs identities that persist: each object of a new map takes the id of the object of the
recent maps it lies nearest to (one-to-one, Hungarian assignment on distance, within a gate);
objects left over get new ids. Ids are local to one robot's maps.
"""

from __future__ import annotations

import numpy as np

from .errors import DataError
from .inputs import check_within, real_array
from .object_map import ObjectMap, as_object_map
from .param_checks import MAX_COORDINATE
from .params import _finite, _int_at_least, _require

__all__ = ["ObjectIdentities", "recent_ids"]


class ObjectIdentities:
    """Persistent ids of one robot's objects across its map exchanges.

    Args:
        gate: metres; an object keeps an earlier id only within this distance of where that
            id was last placed.
        memory: exchanges an id not seen is remembered before it is forgotten.
    """

    def __init__(self, gate: float = 0.3, memory: int = 20) -> None:
        _require(_finite(gate) and gate > 0, "ObjectIdentities", "gate", gate,
                 "must be a finite number > 0 metres")
        _require(_int_at_least(memory, 1), "ObjectIdentities", "memory", memory,
                 "must be an int >= 1")
        self.gate, self.memory = float(gate), int(memory)
        self._xy = np.empty((0, 2))  # last position of each remembered id
        self._ids = np.empty(0, np.int64)
        self._last = np.empty(0, np.int64)  # exchange at which each id was last placed
        self._exchange = 0
        self._next = 0

    def update(self, xy) -> np.ndarray:
        """Ids of the objects of one exchange.

        Args:
            xy: (n, 2) metres, the objects' positions in the robot's odometry frame.
        Returns:
            (n,) int64 ids; equal ids across calls are the same object.
        Raises:
            DataError: xy is not a finite (n, 2) array.
        """
        from scipy.optimize import linear_sum_assignment

        xy = np.array(real_array("ObjectIdentities.update", "xy", xy))  # a copy: it is kept
        if xy.size == 0:
            xy = xy.reshape(0, 2)
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise DataError(f"ObjectIdentities.update: xy must be an (n, 2) array, got "
                            f"shape {xy.shape}")
        check_within("ObjectIdentities.update", "xy", xy, MAX_COORDINATE, "m")
        self._exchange += 1
        n = xy.shape[0]
        ids = np.full(n, -1, np.int64)
        if n and self._ids.size:
            d = np.linalg.norm(xy[:, None, :] - self._xy[None, :, :], axis=2)
            cost = np.where(d <= self.gate, d, 1e6)
            rows, cols = linear_sum_assignment(cost)
            ok = d[rows, cols] <= self.gate
            ids[rows[ok]] = self._ids[cols[ok]]
        new = ids < 0
        ids[new] = self._next + np.arange(np.count_nonzero(new))
        self._next += int(np.count_nonzero(new))
        kept = (self._exchange - self._last < self.memory) & ~np.isin(self._ids, ids)
        self._xy = np.concatenate([self._xy[kept], xy])
        self._ids = np.concatenate([self._ids[kept], ids])
        self._last = np.concatenate([self._last[kept], np.full(n, self._exchange)])
        return ids


def recent_ids(identities: ObjectIdentities, objects: ObjectMap, now: float, kappa: float
               ) -> np.ndarray:
    """(n,) persistent ids of a map's objects seen within kappa seconds of `now` (the ones an
    aligner associates), from `identities.update`; -1 for the older objects.

    Raises:
        DataError: identities not an ObjectIdentities, objects not an ObjectMap, now not a
            finite number or kappa not a number > 0.
    """
    if not isinstance(identities, ObjectIdentities):
        raise DataError(f"recent_ids: identities must be an ObjectIdentities, got "
                        f"{type(identities).__name__}")
    objects = as_object_map("recent_ids", "objects", objects)
    recent = objects.recent_indices(now, kappa)
    ids = np.full(len(objects), -1, np.int64)
    ids[recent] = identities.update(objects.centroids[recent, :2])
    return ids
