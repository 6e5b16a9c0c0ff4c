"""ObjectMap: the sparse map of recently seen objects that a robot shares with its neighbours."""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DataError

__all__ = ["ObjectMap"]

_FIELDS = ("centroids", "widths", "heights", "last_seen")


def _as_float_array(name: str, value, shape_text: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"ObjectMap.{name}: expected numbers with shape {shape_text}, "
                        f"got {type(value).__name__}") from exc
    return arr


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
        centroids = _as_float_array("centroids", self.centroids, "(n, 3)")
        if centroids.size == 0:
            centroids = centroids.reshape(0, 3)
        if centroids.ndim != 2 or centroids.shape[1] != 3:
            raise DataError(f"ObjectMap.centroids: expected shape (n, 3), got {centroids.shape}")
        n = centroids.shape[0]
        arrays = {"centroids": centroids}
        for name in ("widths", "heights", "last_seen"):
            arr = _as_float_array(name, getattr(self, name), "(n,)")
            if arr.size == 0:
                arr = arr.reshape(0)
            if arr.shape != (n,):
                raise DataError(f"ObjectMap.{name}: expected shape ({n},) to match "
                                f"centroids, got {arr.shape}")
            arrays[name] = arr
        for name, arr in arrays.items():
            bad = ~np.isfinite(arr)
            if bad.any():
                index = np.argwhere(bad)[0]
                idx = tuple(int(i) for i in index)
                raise DataError(f"ObjectMap.{name}: non-finite value {arr[idx]} at index "
                                f"{idx if len(idx) > 1 else idx[0]}")
        for name in ("widths", "heights"):
            negative = np.flatnonzero(arrays[name] < 0)
            if negative.size:
                i = int(negative[0])
                raise DataError(f"ObjectMap.{name}: sizes must be >= 0, got {arrays[name][i]} "
                                f"at index {i}")
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
        """(k,) int indices of objects seen less than `kappa` seconds before `now` (l < kappa)."""
        if not np.isfinite(now) or not np.isfinite(kappa) or kappa <= 0:
            raise DataError(f"ObjectMap.recent: need finite now and kappa > 0, "
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
