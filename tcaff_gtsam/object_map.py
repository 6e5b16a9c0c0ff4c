"""ObjectMap: the sparse map of recently seen objects that a robot shares with its neighbours."""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DataError

__all__ = ["ObjectMap", "object_arrays"]

_FIELDS = ("centroids", "widths", "heights", "last_seen")


def object_arrays(prefix: str, centroids, widths, heights, **per_object
                  ) -> dict[str, np.ndarray]:
    """Validated float copies of object fields: centroids (k, 3), widths (k,) and heights (k,)
    in metres, sizes >= 0, plus any other (k,) fields; everything finite. k = 0 is legal.

    Raises:
        DataError: named after the field, `<prefix><field> must have shape (k, 3), got (4, 2)`.
    """
    def as_float(name: str, value) -> np.ndarray:
        try:
            return np.array(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise DataError(f"{prefix}{name} must be numbers, got {type(value).__name__}"
                            ) from exc

    C = as_float("centroids", centroids)
    if C.size == 0:
        C = C.reshape(0, 3)
    if C.ndim != 2 or C.shape[1] != 3:
        raise DataError(f"{prefix}centroids must have shape (k, 3), got {C.shape}")
    k = C.shape[0]
    arrays = {"centroids": C}
    for name, value in {"widths": widths, "heights": heights, **per_object}.items():
        arr = as_float(name, value)
        if arr.size == 0:
            arr = arr.reshape(0)
        if arr.shape != (k,):
            raise DataError(f"{prefix}{name} must have shape ({k},) to match centroids, "
                            f"got {arr.shape}")
        arrays[name] = arr
    for name, arr in arrays.items():
        bad = ~np.isfinite(arr)
        if bad.any():
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            raise DataError(f"{prefix}{name} has non-finite value {arr[idx]} at index "
                            f"{idx if len(idx) > 1 else idx[0]}")
    for name in ("widths", "heights"):
        negative = np.flatnonzero(arrays[name] < 0)
        if negative.size:
            i = int(negative[0])
            raise DataError(f"{prefix}{name} must be >= 0, got {arrays[name][i]} at index {i}")
    return arrays


@dataclass(frozen=True, eq=False)
class ObjectMap:
    """Objects a robot has seen recently, in its own odometry frame.

    Attributes:
        centroids: (n, 3) metres, object centroids in the robot's odometry frame (z up).
        widths: (n,) metres, horizontal extent of each object.
        heights: (n,) metres, vertical extent of each object.
        last_seen: (n,) seconds, time each object was last observed (same clock as `now` below).

    Construction validates shapes, finiteness and non-negative sizes and raises `DataError`
    naming the field; the arrays are copied and made read-only. Empty maps (n = 0) are legal.
    """

    centroids: np.ndarray
    widths: np.ndarray
    heights: np.ndarray
    last_seen: np.ndarray

    def __post_init__(self) -> None:
        arrays = object_arrays("ObjectMap.", self.centroids, self.widths, self.heights,
                               last_seen=self.last_seen)
        for name, arr in arrays.items():
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def empty(cls) -> ObjectMap:
        """A map with no objects."""
        return cls(np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return self.centroids.shape[0]

    def __repr__(self) -> str:
        return f"ObjectMap(n={len(self)})"

    def subset(self, index) -> ObjectMap:
        """The objects selected by a boolean mask (n,) or an integer index array."""
        return ObjectMap(self.centroids[index], self.widths[index], self.heights[index],
                         self.last_seen[index])

    def recent_indices(self, now: float, kappa: float) -> np.ndarray:
        """(k,) int indices of objects seen less than `kappa` seconds before `now` (l < kappa);
        kappa = inf keeps every object."""
        if not np.isfinite(now) or np.isnan(kappa) or kappa <= 0:
            raise DataError(f"ObjectMap.recent_indices: need finite now and kappa > 0, "
                            f"got now={now}, kappa={kappa}")
        return np.flatnonzero(now - self.last_seen < kappa)

    def recent(self, now: float, kappa: float) -> ObjectMap:
        """The objects of `recent_indices` as a map."""
        return self.subset(self.recent_indices(now, kappa))

    def ages(self, now: float) -> np.ndarray:
        """(n,) seconds since each object was last seen; objects stamped after `now` count as 0.

        Robots' clocks are never perfectly in sync, so a slightly future stamp is clipped rather
        than treated as an error.
        """
        return np.maximum(now - self.last_seen, 0.0)

    def save(self, path: str | Path) -> None:
        """Write the map to an npz archive at exactly `path` (arrays named after the fields)."""
        with open(Path(path), "wb") as file:  # a file object stops numpy appending ".npz"
            np.savez(file, **{name: getattr(self, name) for name in _FIELDS})

    @classmethod
    def load(cls, path: str | Path) -> ObjectMap:
        """Read a map written by `save`; raises `DataError` on missing or malformed files."""
        path = Path(path)
        if not path.is_file():
            raise DataError(f"{path}: no such map file")
        try:
            data = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise DataError(f"{path}: cannot read an ObjectMap ({exc})") from exc
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise DataError(f"{path}: not an ObjectMap file (a single array, not an npz archive)")
        with data:
            missing = [name for name in _FIELDS if name not in data.files]
            if missing:
                raise DataError(f"{path}: not an ObjectMap file, missing arrays {missing} "
                                f"(has {sorted(data.files)})")
            try:
                arrays = {name: data[name] for name in _FIELDS}
            except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
                raise DataError(f"{path}: corrupt ObjectMap archive ({exc})") from exc
        return cls(**arrays)
