"""The exception hierarchy: every error the library raises on purpose is a `TcaffError`."""

from __future__ import annotations


class TcaffError(Exception):
    """Root of all errors raised deliberately by tcaff-gtsam."""


class DataError(TcaffError, ValueError):
    """Bad input data: wrong shape, non-finite values, corrupt files, missing topics."""


class ConfigError(TcaffError, ValueError):
    """A parameter or configuration value is out of range or of the wrong kind."""


class ModelError(TcaffError):
    """A model file is missing or does not have the expected signature."""


def reason(exc: BaseException) -> str:
    """The first line of what `exc` says (gtsam's messages begin with a newline and run on),
    or its type's name when it says nothing: for an error of ours that names its cause."""
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__
