"""ObjectMap: the sparse map of recently seen objects that a robot shares with its neighbours."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DataError
from .inputs import finite_time, output_path, read_npz, real_array, shown
from .params import _real

__all__ = ["ObjectMap", "as_object_map", "object_arrays"]

_FIELDS = ("centroids", "widths", "heights", "last_seen")
_ALL_FIELDS = (*_FIELDS, "descriptors")
#: how far from 1 a descriptor's length may be (float32 storage, sums of rounded terms)
_UNIT_TOL = 1e-4


def object_arrays(prefix: str, centroids, widths, heights, **per_object
                  ) -> dict[str, np.ndarray]:
    """Validated float copies of object fields: centroids (k, 3), widths (k,) and heights (k,)
    in metres, sizes >= 0, plus any other (k,) fields; everything finite. k = 0 is legal.

    Raises:
        DataError: named after the field, `<prefix><field> must have shape (k, 3), got (4, 2)`;
            also for values that are not real numbers (complex, strings, objects).
    """
    def as_float(name: str, value) -> np.ndarray:
        arr = _real_numbers(f"{prefix}{name}", value)
        return arr.copy() if arr is value else arr

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


def _real_numbers(label: str, value) -> np.ndarray:
    """`real_array` of `value`, else DataError "<label> must be real numbers, got ..." with
    its type, value and dtype."""
    try:
        return real_array(label, "", value)
    except DataError:
        kind = getattr(value, "dtype", None)
        raise DataError(f"{label} must be real numbers, got {type(value).__name__} "
                        f"{shown(value)}{'' if kind is None else f' of dtype {kind}'}"
                        ) from None


def _descriptor_array(name: str, value, n: int) -> np.ndarray:
    """`value` as a float (n, d) copy (d >= 1) of finite numbers >= 0 in rows of unit length;
    else DataError naming `name`, the row and the value."""
    arr = np.array(_real_numbers(name, value), dtype=np.float64)
    if arr.size == 0 and n == 0:
        return arr.reshape(0, max(arr.shape[-1], 1) if arr.ndim == 2 else 1)
    if arr.ndim != 2 or arr.shape[0] != n or arr.shape[1] < 1:
        raise DataError(f"{name} must have shape ({n}, d) with d >= 1, got {arr.shape}")
    bad = ~np.isfinite(arr) | (arr < 0)
    if bad.any():
        i, j = (int(k) for k in np.argwhere(bad)[0])
        raise DataError(f"{name} must be finite numbers >= 0, got {arr[i, j]} at row {i}, "
                        f"column {j}")
    length = np.sqrt(np.einsum("ij,ij->i", arr, arr))
    off = np.flatnonzero(np.abs(length - 1.0) > _UNIT_TOL)
    if off.size:
        i = int(off[0])
        raise DataError(f"{name} rows must have unit length (L2), row {i} has length "
                        f"{length[i]:.6g}")
    return arr


@dataclass(frozen=True, eq=False)
class ObjectMap:
    """Objects a robot has seen recently, in its own odometry frame.

    Attributes:
        centroids: (n, 3) metres, object centroids in the robot's odometry frame (z up).
        widths: (n,) metres, horizontal extent of each object.
        heights: (n,) metres, vertical extent of each object.
        last_seen: (n,) seconds, time each object was last observed (same clock as `now` below).

        descriptors: (n, d) or None, what each object looks like, for telling apart objects
            of one size (`FrameAlignerParams.descriptor_min`, `descriptor_prior`): rows of
            non-negative numbers of unit length (L2), compared by their dot product, a
            similarity in [0, 1]. The mapping front end fills them with the object's colour
            and shape (`mapping.objects`); appearance embeddings of any kind fit. None: the
            map carries none, and its objects are told apart by size alone.

    Construction validates shapes, finiteness and non-negative sizes and raises `DataError`
    naming the field; the arrays are copied and made read-only. Empty maps (n = 0) are legal.
    """

    centroids: np.ndarray
    widths: np.ndarray
    heights: np.ndarray
    last_seen: np.ndarray
    descriptors: np.ndarray | None = None

    def __post_init__(self) -> None:
        arrays = object_arrays("ObjectMap.", self.centroids, self.widths, self.heights,
                               last_seen=self.last_seen)
        if self.descriptors is not None:
            arrays["descriptors"] = _descriptor_array("ObjectMap.descriptors",
                                                     self.descriptors, len(arrays["widths"]))
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
        """The objects selected by a boolean mask (n,) or a 1-D integer index array (entries in
        [-n, n), negative ones counting from the end as in numpy).

        Raises:
            DataError: a mask of another length, indices out of range, or anything else (a
                float, a scalar, a string) as `index`.
        """
        n = len(self)
        try:
            idx = np.asarray(index)
        except (TypeError, ValueError):
            idx = None
        if idx is not None and idx.size == 0 and idx.dtype.kind in "biuf":
            idx = idx.astype(np.int64).reshape(0)
        if idx is None or idx.ndim != 1 or idx.dtype.kind not in "biu":
            raise DataError(f"ObjectMap.subset: index must be a boolean mask ({n},) or a 1-D "
                            f"integer array, got {shown(index)}")
        if idx.dtype.kind == "b":
            if idx.shape != (n,):
                raise DataError(f"ObjectMap.subset: index is a boolean mask of length "
                                f"{idx.size}, the map has {n} objects")
        elif idx.size and (idx.min() < -n or idx.max() >= n):
            bad = idx[(idx < -n) | (idx >= n)][0]
            raise DataError(f"ObjectMap.subset: index {bad} is out of range for a map of {n} "
                            f"objects")
        # rows of a valid map are valid: the checks of construction are not run again (they
        # cost more than the indexing at the map sizes aligned every second)
        subset = object.__new__(ObjectMap)
        for name in _ALL_FIELDS:
            arr = getattr(self, name)
            if arr is not None:
                arr = arr[idx]  # a copy: numpy's advanced indexing
                arr.setflags(write=False)
            object.__setattr__(subset, name, arr)
        return subset

    def recent_indices(self, now: float, kappa: float) -> np.ndarray:
        """(k,) int indices of objects seen less than `kappa` seconds before `now` (l < kappa);
        kappa = inf keeps every object.

        Raises:
            DataError: now not a finite number, or kappa not a number > 0 (inf allowed).
        """
        owner = "ObjectMap.recent_indices"
        now = finite_time(owner, "now", now)
        if not (_real(kappa) and kappa > 0):  # NaN fails the comparison
            raise DataError(f"{owner}: kappa must be a number > 0 seconds (inf: no limit), "
                            f"got {shown(kappa)}")
        try:
            kappa = float(kappa)
        except OverflowError:  # an int beyond the floats: no limit either
            kappa = math.inf
        return np.flatnonzero(now - self.last_seen < kappa)

    def recent(self, now: float, kappa: float) -> ObjectMap:
        """The objects of `recent_indices` as a map."""
        return self.subset(self.recent_indices(now, kappa))

    def ages(self, now: float) -> np.ndarray:
        """(n,) seconds since each object was last seen; objects stamped after `now` count as 0.

        Robots' clocks are never perfectly in sync, so a slightly future stamp is clipped rather
        than treated as an error.

        Raises:
            DataError: now is not a finite number (a string, None, an array, NaN, inf).
        """
        now = finite_time("ObjectMap.ages", "now", now)
        return np.maximum(now - self.last_seen, 0.0)

    def save(self, path: str | Path) -> None:
        """Write the map to an npz archive at exactly `path` (arrays named after the fields).

        Raises:
            DataError: path not a str or path, a folder, in a missing folder, or not writable.
        """
        path = output_path("ObjectMap.save", path)
        try:
            file = open(path, "wb")  # a file object stops numpy appending ".npz"
        except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the name
            raise DataError(f"ObjectMap.save: cannot write {path} ({exc})") from None
        with file:
            np.savez(file, **{name: getattr(self, name) for name in _ALL_FIELDS
                              if getattr(self, name) is not None})

    @classmethod
    def load(cls, path: str | Path) -> ObjectMap:
        """Read a map written by `save`.

        Raises:
            DataError: naming the file: it is missing, not a regular file (a FIFO, a folder),
                empty, truncated, corrupt (an array header declaring more data than the file
                holds included), not an npz archive, holds arrays of a dtype other than real
                numbers (bool, complex, ...) or invalid maps (shapes, non-finite, ...).
        """
        data = read_npz(path, "map")
        missing = [name for name in _FIELDS if name not in data]
        if missing:
            raise DataError(f"{path}: not an ObjectMap file, missing arrays {missing} "
                            f"(has {sorted(data)})")
        try:
            return cls(**{name: data[name] for name in _ALL_FIELDS if name in data})
        except DataError as exc:
            raise DataError(f"{path}: {exc}") from None


def as_object_map(owner: str, name: str, value) -> ObjectMap:
    """`value` if it is an ObjectMap; else `DataError` naming `owner`, `name` and the type."""
    if not isinstance(value, ObjectMap):
        raise DataError(f"{owner}: {name} must be an ObjectMap, got {type(value).__name__} "
                        f"{shown(value)}")
    return value
