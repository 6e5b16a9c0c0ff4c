"""The checks of `TCAFF.update`'s arguments: measurements, their covariances, object-id
evidence, object counts and a step's growth of a held estimate."""

from __future__ import annotations

import numpy as np

from .errors import DataError
from .geometry import _wrap_angle
from .inputs import check_within, real_array, shown
from .param_checks import MAX_COORDINATE, MAX_VARIANCE
from .params import TCAFFParams
from .tcaff_state import _not_spd

__all__ = ["validated_evidence", "validated_held_Q", "validated_measurements", "validated_objects"]


def validated_measurements(zs, Rs, params: TCAFFParams) -> tuple[np.ndarray, np.ndarray]:
    """zs (k, d) with angles wrapped and Rs (k, d, d) of `TCAFF.update`, checked: real,
    finite, of matching shapes, within the filter's bounds, each R symmetric positive
    definite; DataError naming the argument otherwise."""
    d = params.dim
    zs = real_array("TCAFF.update", "zs", zs)
    Rs = real_array("TCAFF.update", "Rs", Rs)
    if zs.size == 0 and Rs.size == 0:
        return np.empty((0, d)), np.empty((0, d, d))
    if zs.ndim != 2 or zs.shape[1] != d:
        raise DataError(f"TCAFF.update: zs must have shape (k, {d}), got {zs.shape}")
    k = zs.shape[0]
    if Rs.shape != (k, d, d):
        raise DataError(f"TCAFF.update: Rs must have shape ({k}, {d}, {d}) to match zs, "
                        f"got {Rs.shape}")
    # beyond the bounds the filter's sums and squares overflow into NaN states
    check_within("TCAFF.update", "zs", zs, MAX_COORDINATE)
    check_within("TCAFF.update", "Rs", Rs, MAX_VARIANCE)
    bad = _not_spd(Rs)
    if bad is not None:
        i, why = bad
        shown_R = f": {Rs[i].tolist()}" if why == "symmetric" else ""
        raise DataError(f"TCAFF.update: Rs[{i}] is not {why}{shown_R}")
    zs = zs.copy()
    angles = list(params.angle_indices)
    zs[:, angles] = _wrap_angle(zs[:, angles])
    return zs, np.ascontiguousarray(Rs)

def validated_evidence(evidence, k: int) -> list[list[tuple[int, int]] | None] | None:
    """The object-id pairs of `TCAFF.update`'s k measurements (None, or one (m, 2) int
    array or None per measurement) as lists of int pairs; DataError otherwise."""
    if evidence is None:
        return None
    if isinstance(evidence, (str, bytes)) or not hasattr(evidence, "__len__"):
        raise DataError(f"TCAFF.update: evidence must be None or a sequence of {k} "
                        f"entries, got {type(evidence).__name__}")
    if len(evidence) != k:
        raise DataError(f"TCAFF.update: evidence has {len(evidence)} entries for {k} "
                        f"measurements")
    out: list[list[tuple[int, int]] | None] = []
    for i, pairs in enumerate(evidence):
        if pairs is None:
            out.append(None)
            continue
        try:
            arr = np.asarray(pairs)
        except (TypeError, ValueError):  # ragged nested sequences
            arr = None
        if arr is not None and arr.size == 0:
            arr = arr.reshape(0, 2)
        if arr is None or arr.ndim != 2 or arr.shape[1] != 2 or arr.dtype.kind not in "iu":
            got = (shown(pairs) if arr is None else
                   f"shape {arr.shape} of {arr.dtype}: {shown(pairs)}")
            raise DataError(f"TCAFF.update: evidence[{i}] must be an (m, 2) int array of "
                            f"object-id pairs, got {got}")
        out.append([(int(a), int(b)) for a, b in arr])
    return out

def validated_objects(objects, k: int) -> np.ndarray | None:
    """The object counts of `TCAFF.update`'s k measurements as (k,) int64 (None: none
    given); DataError unless whole counts in [0, 2**31)."""
    if objects is None:
        return None
    arr = real_array("TCAFF.update", "objects", objects)
    if arr.shape != (k,):
        raise DataError(f"TCAFF.update: objects must have shape ({k},), one count per "
                        f"measurement, got shape {arr.shape}")
    if (np.asarray(objects).dtype == bool or not np.all(np.isfinite(arr))
            or np.any(arr != np.round(arr)) or np.any(arr < 0) or np.any(arr >= 2**31)):
        raise DataError(f"TCAFF.update: objects must be whole counts in [0, 2**31), got "
                        f"{shown(objects)}")
    return arr.astype(np.int64)


def validated_held_Q(held_Q, params: TCAFFParams) -> np.ndarray | None:
    """`TCAFF.update`'s held_Q checked: None, or a real symmetric positive definite (d, d)
    matrix within MAX_VARIANCE, given to a filter that holds by a `held_Q` of its own;
    DataError naming the argument otherwise."""
    if held_Q is None:
        return None
    d = params.dim
    if params.held_Q is None:
        raise DataError("TCAFF.update: held_Q was given, but the filter's params.held_Q is "
                        "None: it grows a held estimate by Q alone")
    M = real_array("TCAFF.update", "held_Q", held_Q)
    if M.shape != (d, d):
        raise DataError(f"TCAFF.update: held_Q must have shape ({d}, {d}), got {M.shape}")
    check_within("TCAFF.update", "held_Q", M, MAX_VARIANCE)
    bad = _not_spd(M[None])
    if bad is not None:
        raise DataError(f"TCAFF.update: held_Q is not {bad[1]}: {M.tolist()}")
    return M
