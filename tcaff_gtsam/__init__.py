"""tcaff-gtsam: robot frame alignment by temporal consistency (TCAFF) with a GTSAM back end.

The estimation core: object maps, CLIPPER association, MNO-CLIPPER, weighted Arun, the frame
aligner, the TCAFF filter and the iSAM2 inter-robot graph. No file formats beyond map and
filter save/load, no printing, no plotting.
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
from .graph import InterRobotGraph
from .object_map import ObjectMap
from .pairwise import PairwiseAligner
from .params import ClipperParams, FrameAlignerParams, GraphParams, TCAFFParams
from .registration import putative_associations, weighted_arun
from .tcaff import TCAFF, AlignmentEstimate

__version__ = "0.1.0"

__all__ = [
    "TCAFF",
    "AlignmentEstimate",
    "AlignmentMeasurement",
    "ClipperParams",
    "ClipperSolution",
    "ConfigError",
    "ConsistencyGraph",
    "DataError",
    "FrameAligner",
    "FrameAlignerParams",
    "GraphParams",
    "InterRobotGraph",
    "ModelError",
    "ObjectMap",
    "PairwiseAligner",
    "TCAFFParams",
    "TcaffError",
    "clipper_solve",
    "consistency_graph",
    "mno_clipper",
    "putative_associations",
    "weighted_arun",
]
