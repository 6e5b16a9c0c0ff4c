"""What every parameter object checks its fields with, and the error it raises: `ParameterError`,
a `ConfigError` that names the field, its value and the rule it breaks."""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

import numpy as np

from .errors import ConfigError

# -- the largest values a parameter takes ------------------------------------------------------
# Every numeric field of the parameter objects is bounded by one of these, so that a value no
# robot would use is refused by name when the object is made, not found later as an overflow
# (or as an input a later check refuses under another name).

#: metres; coordinates beyond this are no robot's odometry (and squared sums of them overflow
#: long before they would stop being rounding noise); lengths of the settings too
MAX_COORDINATE = 1e9
#: the largest entry of a covariance: the square of MAX_COORDINATE, (m^2 or rad^2)
MAX_VARIANCE = MAX_COORDINATE**2
#: seconds, the longest duration a setting names (a map's span, the memory of earlier maps):
#: a year of 365.25 days, far past any mission
MAX_SECONDS = 31_557_600
#: the most steps a setting counts (how long a hypothesis is kept, recalled, reported): a year
#: of steps at 10 Hz, beyond the 1 Hz at which maps are exchanged
MAX_STEPS = 10 * MAX_SECONDS
#: nats, the largest cost or evidence a setting names: the cost of a thousand-step window
#: (MAX_WINDOW) whose every step is as unlikely as the smallest positive float (e^-745)
MAX_NATS = 1e6
#: the largest dimensionless factor, ratio or count of standard deviations a setting names
#: (defaults are between 0.1 and 4)
MAX_FACTOR = 1e6
#: the most objects or associations a count names: a consistency graph of a million
#: associations would cost 5e11 distance checks per search
MAX_OBJECTS = 1_000_000
#: the most iterations of a CLIPPER loop (each ascent step or power step costs a pass over the
#: graph; the defaults are 5 to 1000)
MAX_ITERATIONS = 1_000_000


class ParameterError(ConfigError):
    """A `ConfigError` about one field of a parameter object.

    Attributes:
        owner: the parameter class (or function) the field belongs to.
        name: the field.
        value: the rejected value.
        rule: what the field must be, e.g. "must be an int >= 1".
    """

    def __init__(self, owner: str, name: str, value: Any, rule: str) -> None:
        try:
            shown = repr(value)
        except Exception:  # an int beyond Python's digit limit, a broken __repr__
            shown = f"<{type(value).__name__} that has no repr>"
        super().__init__(f"{owner}.{name} = {shown}: {rule}")
        self.owner, self.name, self.value, self.rule = owner, name, value, rule

    def __reduce__(self):
        # the default rebuilds from `args` (the message alone), which this __init__ refuses;
        # errors of study jobs travel between processes
        return type(self), (self.owner, self.name, self.value, self.rule)


def _require(condition: bool, owner: str, name: str, value, rule: str) -> None:
    if not condition:
        raise ParameterError(owner, name, value, rule)


def _given_or_default(cls: type, value, owner: str, name: str = "params"):
    """`value` when it is a `cls`, `cls()` when it is None; a ConfigError naming `owner` and
    `name` otherwise."""
    if value is None:
        return cls()
    _require(isinstance(value, cls), owner, name, value, f"must be a {cls.__name__} or None")
    return value


def _int_at_least(value, low: int, high: int | None = None) -> bool:
    """An int (Python or numpy, not a bool) >= low, and <= high unless high is None."""
    return (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= low
            and (high is None or value <= high))


def _bound(x: float) -> str:
    """A bound as a message shows it: 1e9 as 1e9, 31557600 as it is, pi as pi."""
    if x == math.pi:
        return "pi"
    if isinstance(x, int) or (float(x).is_integer() and abs(x) < 1e6):
        return str(int(x))
    return f"{x:g}".replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


def _count(owner: str, name: str, value, low: int, high: int, limit: str = "",
           none: bool = False) -> None:
    """A `ParameterError` unless `value` is an int in [low, high] (or None, when `none`);
    `limit` names the constant `high` is."""
    ok = (none and value is None) or _int_at_least(value, low, high)
    rule = f"must be an int in [{low}, {high}]" + (f" ({limit})" if limit else "")
    _require(ok, owner, name, value, rule + (" or None" if none else ""))


def _number(owner: str, name: str, value, low: float, high: float, unit: str = "",
            limit: str = "", above: bool = False, none: bool = False,
            inf: bool = False) -> None:
    """A `ParameterError` unless `value` is a real number (not a bool) >= low (> low when
    `above`) and <= high, or None when `none`, or +inf when `inf` (a limit of none). Exact for
    ints beyond the floats: 10**400 is compared, never converted."""
    ok = ((none and value is None) or (inf and _real(value) and value == math.inf)
          or (_real(value) and (value > low if above else value >= low) and value <= high))
    rule = (f"must be a {'' if inf else 'finite '}number {'>' if above else '>='} "
            f"{_bound(low)} and <= {_bound(high)}" + (f" {unit}" if unit else "")
            + (f" ({limit})" if limit else ""))
    if inf:
        rule += ", or inf (no limit)"
    _require(ok, owner, name, value, rule + (" or None" if none else ""))


#: the largest count the compiled kernels take
_INT64_MAX = 2**63 - 1


def _real(value) -> bool:
    """A real number (Python or numpy, not a bool); may be NaN or infinite."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _finite(value) -> bool:
    """A finite real number (Python or numpy, not a bool); False for ints beyond the floats,
    which numpy cannot take."""
    try:
        return _real(value) and math.isfinite(value)
    except OverflowError:
        return False


def _one_of(value, choices: tuple) -> bool:
    """One of `choices` (strings or ints) by type as well as value: 2.0 is not 2, True not 1."""
    return (isinstance(value, (str, int, np.integer)) and not isinstance(value, bool)
            and value in choices)


def _reals(value) -> tuple[float, ...] | None:
    """A sequence (tuple, list or 1-D array) of real numbers as a tuple of floats, else None."""
    if isinstance(value, np.ndarray) and value.ndim == 1:
        value = value.tolist()
    if not isinstance(value, (tuple, list)) or not all(_real(v) for v in value):
        return None
    try:
        return tuple(float(v) for v in value)
    except OverflowError:  # an int beyond the floats
        return None


def _spd(matrix, d: int | None, owner: str, name: str, bounded: bool = False) -> np.ndarray:
    """`matrix` as a new float (d, d) array if it is a symmetric positive definite matrix of
    real numbers (d None: of any size >= 1), with `bounded` entries of magnitude at most
    MAX_VARIANCE (else any finite); else `ParameterError`."""
    try:
        M = np.array(matrix) if isinstance(matrix, (tuple, list, np.ndarray)) else None
    except ValueError:  # ragged nested lists
        M = None
    ok = (M is not None and M.dtype.kind in "iuf" and M.ndim == 2 and M.shape[0] >= 1
          and M.shape[0] == M.shape[1] and (d is None or M.shape[0] == d))
    if ok:
        # + 0.0 turns -0.0 into 0.0, so matrices equal by value are equal byte for byte
        M = M.astype(float) + 0.0
        ok = (bool(np.all(np.isfinite(M))) and (not bounded or np.abs(M).max() <= MAX_VARIANCE)
              and np.allclose(M, M.T) and bool(np.all(np.linalg.eigvalsh(M) > 0)))
    size = "(d, d)" if d is None else f"({d}, {d})"
    entries = (f" with entries of magnitude <= {_bound(MAX_VARIANCE)} (MAX_VARIANCE)"
               if bounded else "")
    _require(ok, owner, name, matrix,
             f"must be a symmetric positive definite {size} matrix{entries}")
    return M


def _frozen(value):
    """`value`, or for an array a hashable stand-in equal exactly when the arrays are."""
    if isinstance(value, np.ndarray):
        return value.shape, value.dtype.str, value.tobytes()
    return value


class _ByValue:
    """Equality and hashing of a frozen parameter dataclass by the values of its fields, arrays
    included (the dataclass's own `__eq__` compares arrays elementwise and cannot hash them).
    Its subclasses are declared with `eq=False` so that these methods stay in place. The arrays
    are the object's own copies and must not be modified in place."""

    def _key(self) -> tuple:
        return tuple(_frozen(getattr(self, f.name)) for f in fields(self))

    def __eq__(self, other) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())
