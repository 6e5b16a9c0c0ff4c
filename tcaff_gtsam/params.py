"""Parameter objects. Defaults are the paper's values (and the released code's where the paper
is silent); every object validates itself and raises `ConfigError` naming the field.

The objects live by subject: `aligner_params` (CLIPPER and the frame aligner),
`filter_params` (TCAFF and the iSAM2 graph), and `param_checks`, the field checks they share
(which the other modules' argument checks use too). This module gathers them under one name.
"""

from __future__ import annotations

from .aligner_params import (  # noqa: F401 (the drift default is the graph's too)
    MAX_SOLUTIONS,
    ClipperParams,
    FrameAlignerParams,
    _alignment_process_noise,
    constant_alignment_covariance,
)
from .filter_params import MAX_WINDOW, GraphParams, TCAFFParams
from .param_checks import (  # noqa: F401 (the checks every module's arguments take)
    _INT64_MAX,
    ParameterError,
    _finite,
    _given_or_default,
    _int_at_least,
    _real,
    _reals,
    _require,
    _spd,
)

__all__ = [
    "MAX_SOLUTIONS",
    "MAX_WINDOW",
    "ClipperParams",
    "FrameAlignerParams",
    "GraphParams",
    "ParameterError",
    "TCAFFParams",
    "constant_alignment_covariance",
]
