"""How big a thing the generators make: the checks of a caller-given count or amount that
decides how much they allocate, each raising `DataError` naming the function, the argument,
its value and the limit it breaks."""

from __future__ import annotations

import math

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.inputs import shown
from tcaff_gtsam.params import _finite, _int_at_least

__all__ = ["amount", "count"]


def count(owner: str, name: str, value, high: int, limit: str, low: int = 0) -> int:
    """`value` as an int if it is an int (Python or numpy, not a bool) in [low, high]; else
    DataError "owner: name = value: must be an int in [low, high] (limit)", `limit` naming the
    constant `high` comes from."""
    if not (_int_at_least(value, low) and value <= high):
        raise DataError(f"{owner}: {name} = {shown(value)}: must be an int in [{low}, {high}] "
                        f"({limit})")
    return int(value)


def amount(owner: str, name: str, value, high: float = math.inf, limit: str = "",
           low: float = 0.0) -> float:
    """`value` as a float if it is a finite real number (not a bool) in [low, high]; else
    DataError as `count`'s (high infinite: any finite number >= low)."""
    if not (_finite(value) and low <= value <= high):
        rule = (f">= {low:g}" if high == math.inf
                else f"in [{low:g}, {high:g}] ({limit})")
        raise DataError(f"{owner}: {name} = {shown(value)}: must be a finite number {rule}")
    return float(value)
