"""tcaff-gtsam: robot frame alignment by temporal consistency (TCAFF) with a GTSAM back end.

The estimation core: object maps, CLIPPER association, MNO-CLIPPER, weighted Arun and the
frame aligner. No file formats beyond map save/load, no printing, no plotting.
"""

from .clipper import (
    ClipperSolution,
    ConsistencyGraph,
    clipper_solve,
    consistency_graph,
    mno_clipper,
)
from .errors import ConfigError, DataError, ModelError, TcaffError
from .frame_aligner import AlignmentMeasurement, FrameAligner
from .object_map import ObjectMap
from .params import ClipperParams, FrameAlignerParams
from .registration import putative_associations, weighted_arun

__version__ = "0.1.0"

__all__ = [
    "AlignmentMeasurement",
    "ClipperParams",
    "ClipperSolution",
    "ConfigError",
    "ConsistencyGraph",
    "DataError",
    "FrameAligner",
    "FrameAlignerParams",
    "ModelError",
    "ObjectMap",
    "TcaffError",
    "clipper_solve",
    "consistency_graph",
    "mno_clipper",
    "putative_associations",
    "weighted_arun",
]
