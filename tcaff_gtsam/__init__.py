"""tcaff-gtsam: robot frame alignment by temporal consistency (TCAFF) with a GTSAM back end.

The estimation core: object maps, CLIPPER association, MNO-CLIPPER, weighted Arun, the frame
aligner, the TCAFF filter, team consistency and the iSAM2 inter-robot graph. No file formats
beyond map and filter save/load, no printing, no plotting.

The public names below load their module on first use (PEP 562), so `import tcaff_gtsam` stays
cheap: gtsam, numba and scipy are loaded only by the parts that need them.
"""

import importlib as _importlib
from typing import TYPE_CHECKING as _TYPE_CHECKING

from .errors import ConfigError, DataError, ModelError, TcaffError

if _TYPE_CHECKING:
    from .association import putative_associations
    from .clipper import (
        ClipperSolution,
        ConsistencyGraph,
        clipper_solve,
        consistency_graph,
        mno_clipper,
    )
    from .frame_aligner import AlignmentMeasurement, FrameAligner, MapMemory
    from .graph import InterRobotGraph
    from .identities import ObjectIdentities
    from .object_map import ObjectMap
    from .pairwise import PairwiseAligner
    from .params import ClipperParams, FrameAlignerParams, GraphParams, TCAFFParams
    from .registration import weighted_arun
    from .tcaff import TCAFF, AlignmentEstimate
    from .team import TeamConsistency, TeamEstimate, TeamParams

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
    "MapMemory",
    "ModelError",
    "ObjectIdentities",
    "ObjectMap",
    "PairwiseAligner",
    "TCAFFParams",
    "TcaffError",
    "TeamConsistency",
    "TeamEstimate",
    "TeamParams",
    "clipper_solve",
    "consistency_graph",
    "mno_clipper",
    "putative_associations",
    "weighted_arun",
]

# public name -> the submodule that defines it
_LAZY = {
    "ClipperSolution": "clipper",
    "ConsistencyGraph": "clipper",
    "clipper_solve": "clipper",
    "consistency_graph": "clipper",
    "mno_clipper": "clipper",
    "AlignmentMeasurement": "frame_aligner",
    "FrameAligner": "frame_aligner",
    "MapMemory": "frame_aligner",
    "InterRobotGraph": "graph",
    "ObjectIdentities": "identities",
    "ObjectMap": "object_map",
    "PairwiseAligner": "pairwise",
    "ClipperParams": "params",
    "FrameAlignerParams": "params",
    "GraphParams": "params",
    "TCAFFParams": "params",
    "putative_associations": "association",
    "weighted_arun": "registration",
    "TCAFF": "tcaff",
    "AlignmentEstimate": "tcaff",
    "TeamConsistency": "team",
    "TeamEstimate": "team",
    "TeamParams": "team",
}

# Submodules an eager import used to bind as attributes (`tcaff_gtsam.geometry.wrap_angle`
# after a bare `import tcaff_gtsam`); they stay reachable that way.
_SUBMODULES = frozenset({"clipper", "errors", "frame_aligner", "geometry", "graph",
                         "hypothesis_tree", "identities", "object_map", "pairwise", "params",
                         "registration", "tcaff", "team"})


def __getattr__(name: str) -> object:
    if name in _LAZY:
        value = getattr(_importlib.import_module(f".{_LAZY[name]}", __name__), name)
    elif name in _SUBMODULES:
        value = _importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    dunders = {name for name in globals() if name.startswith("__")}
    return sorted(dunders | set(__all__) | _SUBMODULES)
