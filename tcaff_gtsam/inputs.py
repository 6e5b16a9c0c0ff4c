"""Checks of input data shared by the modules: each raises `DataError` naming the function, the
argument and the value given, e.g. `ObjectMap.ages: now must be a finite number of seconds,
got 'soon'`. Scalars and small arrays only, or one vectorised pass over an array: these run
on every step of every robot pair.
"""

from __future__ import annotations

import math
import os
import stat
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .errors import DataError
from .param_checks import MAX_COORDINATE
from .params import _real

__all__ = ["finite_time", "index_pairs", "output_path", "read_npz", "real_array", "shown"]


def shown(value, limit: int = 60) -> str:
    """A short repr of a rejected value for an error message (arrays by shape and dtype), at
    most `limit` characters (an int >= 4)."""
    if not (isinstance(limit, int) and not isinstance(limit, bool) and limit >= 4):
        raise DataError(f"shown: limit must be an int >= 4 characters, got {limit!r:.40}")
    if isinstance(value, np.ndarray) and value.size > 6:
        return f"array of shape {value.shape} and dtype {value.dtype}"
    try:
        text = " ".join(repr(value).split())
    except Exception:  # a broken __repr__ must not hide the error being reported
        text = f"<{type(value).__name__}>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def kernel_array(value: np.ndarray, dtype: type = np.float64) -> np.ndarray:
    """`value`, an array the caller has checked, as a C-contiguous, writeable array of
    `dtype`, for a numba kernel (not public: no checks of its own): the array itself where it
    is one, else a copy. numba compiles a kernel again for read-only arrays (an
    ObjectMap's, np.broadcast_to's), seconds on a process's first use, as the cache that
    `compile_kernels` fills holds the writeable ones."""
    array = np.ascontiguousarray(value, dtype)
    return array if array.flags.writeable else array.copy()


def finite_time(owner: str, name: str, value) -> float:
    """`value` as a float if it is a finite real number (Python or numpy, not a bool, not an
    array); else `DataError` naming `owner` and `name`."""
    if _real(value):
        try:
            t = float(value)
        except OverflowError:  # an int beyond the float range
            t = math.inf
        if math.isfinite(t):
            return t
    why = "not finite" if _real(value) else f"a {type(value).__name__}"
    raise DataError(f"{owner}: {name} must be a finite number of seconds, got {shown(value)} "
                    f"({why})")


def real_array(owner: str, name: str, value) -> np.ndarray:
    """`value` as a float64 array (not copied when it already is one). Numbers only: booleans,
    complex values, strings, bytes, dates and other objects are refused rather than cast (numpy
    would take True as 1, drop an imaginary part or parse a string). Shape and finiteness are
    the caller's to check.

    Raises:
        DataError: naming `owner` and `name`.
    """
    if isinstance(value, np.ndarray) and value.dtype == np.float64:
        return value
    try:
        arr = np.asarray(value)
        if arr.dtype.kind not in "iuf":
            raise TypeError(f"values of dtype {arr.dtype}")
        return arr.astype(np.float64, copy=False)
    except (TypeError, ValueError, OverflowError) as exc:
        raise DataError(f"{owner}: {name} must be real numbers, got {shown(value)} ({exc})"
                        ) from None


def check_within(owner: str, name: str, arr: np.ndarray, bound: float, unit: str = "") -> None:
    """DataError naming the first entry of `arr` that is not finite or beyond `bound` in
    magnitude (`param_checks.MAX_COORDINATE`, `MAX_VARIANCE`: past them sums and squares
    overflow). One comparison on the usual path: NaN fails it."""
    within = np.abs(arr) <= bound
    if not within.all():
        at = tuple(int(k) for k in np.argwhere(~within)[0])
        value = arr[at]
        why = (f"beyond {bound:g}{' ' + unit if unit else ''}" if np.isfinite(value)
               else "not finite")
        raise DataError(f"{owner}: {name}[{', '.join(map(str, at))}] = {value} is {why}")


def point_array(owner: str, name: str, value, d: int | None = None) -> np.ndarray:
    """`value` as (k, d) points, d = 2 or 3 (or the given d), finite and within
    `MAX_COORDINATE` metres (past it their squares overflow: a spread of 1e160 m came out
    NaN), else DataError naming `owner` and `name`."""
    arr = real_array(owner, name, value)
    if arr.ndim != 2 or (arr.shape[1] not in (2, 3) if d is None else arr.shape[1] != d):
        raise DataError(f"{owner}: {name} must be (k, {'2 or 3' if d is None else d}) points, "
                        f"got shape {arr.shape}")
    check_within(owner, name, arr, MAX_COORDINATE, "m")
    return arr


def index_pairs(owner: str, name: str, value) -> np.ndarray:
    """`value` as an (m, 2) int64 array of non-negative indices, e.g. associations (ego index,
    other index). Integers, or floats with whole values; never reshaped, never rounded.

    Raises:
        DataError: naming `owner` and `name`: not an (m, 2) array (an (m, 3) array is not
            read as pairs), fractional or non-finite values, negative indices.
    """
    if isinstance(value, np.ndarray) and value.dtype == np.int64:
        arr = value
    else:
        try:
            arr = np.asarray(value)
        except (TypeError, ValueError) as exc:
            raise DataError(f"{owner}: {name} must be an (m, 2) array of indices, got "
                            f"{shown(value)} ({exc})") from None
        if arr.size == 0 and arr.dtype.kind in "biuf":
            arr = arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise DataError(f"{owner}: {name} must be an (m, 2) array of index pairs, got shape "
                        f"{arr.shape}")
    if arr.dtype.kind == "f":
        whole = np.isfinite(arr) & (arr == np.floor(arr))
        if not whole.all():
            i, j = np.argwhere(~whole)[0]
            raise DataError(f"{owner}: {name} must hold whole numbers, got {arr[i, j]} at "
                            f"[{i}, {j}]")
    elif arr.dtype.kind not in "iu":
        raise DataError(f"{owner}: {name} must be an (m, 2) array of integer indices, got "
                        f"dtype {arr.dtype}")
    if arr.size and arr.min() < 0:
        i, j = np.argwhere(arr < 0)[0]
        raise DataError(f"{owner}: {name} must be indices >= 0, got {arr[i, j]} at [{i}, {j}]")
    # compared as floats: a float16 array would overflow casting int64's maximum to its dtype
    if arr.size and float(arr.max()) >= 2.0**63:
        raise DataError(f"{owner}: {name} holds an index beyond int64, {arr.max()}")
    return arr.astype(np.int64, copy=False)


def write_whole(path: Path, text: str) -> None:
    """Write `text` to `path` whole or not at all: aside (`<path>.partial`), then renamed over
    it, so that a process killed while writing (SIGKILL, a crash) leaves the previous file whole.
    The bytes reach the disk before the rename, so that a robot whose power is cut just after
    finds the new file whole rather than empty (file systems may write the rename first)."""
    partial = path.with_name(path.name + ".partial")
    try:
        with open(partial, "w", encoding="utf-8", newline="") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(partial, path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


def output_path(owner: str, path) -> Path:
    """`path` as a Path to write a file to: a str or path-like naming no folder, in a folder
    that exists.

    Raises:
        DataError: naming `owner`: not a str or path, a folder, or a missing parent folder.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise DataError(f"{owner}: path must be a str or a path, got {shown(path)}")
    out = Path(path)
    if out.is_dir():
        raise DataError(f"{owner}: {out} is a folder, not a file")
    if not out.parent.is_dir():
        raise DataError(f"{owner}: the folder {out.parent} does not exist")
    return out


# -- npz archives --------------------------------------------------------------------------------

#: deflate expands at most about 1032:1; a member claiming more is corrupt
_MAX_EXPANSION = 1100
#: the dtype kinds the archives hold: real numbers (int, unsigned, float) and text (names,
#: parameters as JSON). Others are refused here, bool above all: the loaders' casts take it as
#: 0 and 1 without a word (boolean centroids would be aligned).
_STORED_KINDS = frozenset("iufUS")
_READ_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error,
                NotImplementedError, RuntimeError, KeyError, IndexError, OverflowError,
                SyntaxError, MemoryError)


class NotRegularFile(OSError):
    """A path that names a folder, FIFO or device where a file's bytes are to be read."""

    def __str__(self) -> str:
        return "not a regular file (a folder, FIFO or device)"


def open_regular(path: str | Path):
    """`path` opened to read its bytes, with its `os.stat_result`, if it is a regular file.

    It is checked before it is opened, as a FIFO would block the open until a writer came,
    and again on the file opened (without waiting, O_NONBLOCK), should one be swapped in
    between.

    Raises:
        FileNotFoundError; NotRegularFile; another OSError (no permission, ...) or ValueError
        (a NUL in the path): for the caller to name in its own DataError.
    """
    if not stat.S_ISREG(os.stat(path).st_mode):
        raise NotRegularFile()
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise NotRegularFile()
        return os.fdopen(fd, "rb"), info
    except BaseException:
        os.close(fd)
        raise


def read_npz(path: str | Path, what: str, *, bools: bool = False) -> dict[str, np.ndarray]:
    """Every array of an npz archive (`np.savez`, compressed or not), without pickles.

    Refuses, before reading anything, a path that is not a regular file (a FIFO would block
    forever), and, before reading an array, one whose header declares more data than the
    archive holds (a tampered shape would make numpy allocate it) or a dtype other than real
    numbers and text (bool, complex, dates, records, Python objects).

    Args:
        path: the archive.
        what: what the file should hold, for the messages ("map", "TCAFF filter").
        bools: also take bool arrays, for a caller that checks which arrays may be masks.
    Raises:
        DataError: a path that is no path, a file missing, not a regular file, not an npz
            archive, corrupt or truncated, or an array of another dtype (naming the array).
    """
    try:
        path = Path(path)
    except TypeError:
        raise DataError(f"the {what} file must be a path, got {shown(path)}") from None

    try:
        file, info = open_regular(path)
    except FileNotFoundError:
        raise DataError(f"{path}: no such {what} file") from None
    except NotRegularFile as exc:
        raise DataError(f"{path}: {exc}, not a saved {what}") from None
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot open the {what} file ({exc})") from None
    if info.st_size == 0:
        file.close()
        raise DataError(f"{path}: empty file, not a saved {what}")
    with file:
        try:
            return _read_members(file, info.st_size, path, what,
                                 _STORED_KINDS | {"b"} if bools else _STORED_KINDS)
        except DataError:
            raise
        except _READ_ERRORS as exc:
            raise DataError(f"{path}: not a saved {what} ({type(exc).__name__}: {exc})"
                            ) from None


def _read_members(file, size: int, path: Path, what: str, kinds: frozenset[str]
                  ) -> dict[str, np.ndarray]:
    fmt = np.lib.format
    arrays = {}
    with zipfile.ZipFile(file) as archive:
        for member in archive.infolist():
            if not member.filename.endswith(".npy"):
                continue
            name = member.filename[:-4]
            if member.compress_size > size or (member.file_size > _MAX_EXPANSION
                                               * member.compress_size + 4096):
                raise DataError(f"{path}: corrupt {what} archive, member {name!r} claims "
                                f"{member.file_size} bytes")
            with archive.open(member) as stream:
                version = fmt.read_magic(stream)
                if version not in ((1, 0), (2, 0)):
                    raise DataError(f"{path}: array {name!r} has npy format version "
                                    f"{version}, expected 1.0 or 2.0")
                read_header = (fmt.read_array_header_1_0 if version == (1, 0)
                               else fmt.read_array_header_2_0)
                shape, _, dtype = read_header(stream)
                header = stream.tell()
            if dtype.kind not in kinds:
                raise DataError(f"{path}: array {name!r} has dtype {dtype}, not real numbers")
            declared = math.prod(shape) * dtype.itemsize
            if declared != member.file_size - header:
                raise DataError(f"{path}: corrupt {what} archive, array {name!r} declares "
                                f"shape {shape} of {dtype} ({declared} bytes) but holds "
                                f"{member.file_size - header} bytes")
            with archive.open(member) as stream:
                arrays[name] = fmt.read_array(stream, allow_pickle=False)
    return arrays
