"""Configuration of the recorded data sets (`config`): a Kimera-Multi test (robots, bags, topics,
the RGB-D rig's extrinsics), an MRCLAM evaluation (odometry, VIO-like drift, map spans) and an
RGB-D sequence evaluation (7-Scenes, TUM RGB-D), each naming the method set that aligns its maps.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator, model_validator
from tcaff_gtsam.mapping.mapper import MapperParams

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.params import TCAFFParams

from .config_base import FILE_NAME, GraphDrift, _Finite, _rule_of
from .config_methods import MethodsConfig, ThresholdConfig
from .config_scenario import MappingConfig


class ExtrinsicsConfig(_Finite):
    """A sensor frame in a parent frame: `xyz` metres, then `rpy_deg` (roll, pitch, yaw about
    the parent's fixed x, y, z axes, ROS order). `matrix` (16 numbers, row-major 4 x 4) replaces
    both when given."""

    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    matrix: list[float] | None = Field(None, min_length=16, max_length=16)


class RgbdRigConfig(_Finite):
    """The RGB-D camera of a robot in a recorded data set."""

    body_color: ExtrinsicsConfig = Field(
        ExtrinsicsConfig(xyz=(0.2, 0.0, 0.6), rpy_deg=(0.0, 5.0, 0.0)), description=(
            "the colour camera in the body frame (x forward, y left, z up). Without `matrix`, "
            "xyz/rpy place a camera link looking along its x axis and the optical frame "
            "(x right, y down, z forward) is turned from it; `matrix` is the optical frame "
            "itself, as in Kimera's T_BS"))
    color_depth: ExtrinsicsConfig = Field(
        ExtrinsicsConfig(xyz=(-0.059, 0.0, 0.0)),
        description="the depth camera's optical frame in the colour camera's optical frame")
    depth_scale: float = Field(1000.0, gt=0, description="raw depth units per metre")


class TopicsConfig(_Finite):
    """Topic names of one robot; `{robot}` is replaced by its name."""

    color: str = "/{robot}/forward/color/image_raw/compressed"
    color_info: str = "/{robot}/forward/color/camera_info"
    depth: str = "/{robot}/forward/depth/image_rect_raw"
    depth_info: str = "/{robot}/forward/depth/camera_info"
    odometry: str = "/{robot}/jackal_velocity_controller/odom"

    def of(self, robot: str) -> dict[str, str]:
        """Role -> topic name for `robot`."""
        return {role: topic.replace("{robot}", robot) for role, topic in self}


class KimeraMultiConfig(_Finite):
    """One Kimera-Multi test: which robots' bags to map and align, and how."""

    name: str = Field(min_length=1, pattern=FILE_NAME)
    description: str = ""
    robots: list[str] = Field(min_length=2)
    bags: str = Field("*{robot}*.bag", description=(
        "glob under --data for each robot's bags, `{robot}` replaced by its name"))
    ground_truth: str = Field("{robot}_gt_odom.csv",
                              description="each robot's ground-truth CSV under --data")
    topics: TopicsConfig = TopicsConfig()
    rig: RgbdRigConfig = RgbdRigConfig()
    stride: int = Field(1, ge=1, description=(
        "of the frames kept at mapping.frame_rate, map every stride-th"))
    sync_tolerance: float = Field(0.02, ge=0, description="s, colour to depth stamp")
    start: float | None = Field(None, ge=0, description="s after the first frame to begin")
    duration: float | None = Field(None, gt=0, description="s of data to use (default: all)")
    mapping: MappingConfig = MappingConfig()
    window: Annotated[int | None, _rule_of(TCAFFParams, "window")] = Field(
        None, description="TCAFF window W of every TCAFF method; None: each preset's")
    graph_drift: GraphDrift = Field(
        None, description="iSAM2 between-step drift (m, deg) per 1 Hz step; None: TCAFF's Q")
    methods: str | MethodsConfig = "default"

    @field_validator("robots")
    @classmethod
    def _robots(cls, value: list[str]) -> list[str]:
        # a name goes into the bags' glob and into file names: no pattern or path in it
        if (len(set(value)) != len(value)
                or not all(re.fullmatch(FILE_NAME, name) for name in value)):
            raise ValueError(f"robots must be distinct names of letters, digits, '_', '.' "
                             f"and '-', got {value}")
        return value

    @field_validator("bags")
    @classmethod
    def _bags(cls, value: str) -> str:
        if "{robot}" not in value or value.startswith(("/", "~")) or ".." in value.split("/"):
            raise ValueError(f"bags must be a glob relative to --data that holds {{robot}} "
                             f"(each robot its own bags), got {value!r}")
        return value


class VioDriftConfig(_Finite):
    """Visual-inertial-like odometry made from the true poses: the heading takes a random walk
    and every distance driven is scaled by (1 + e), e drawn once per robot."""

    heading_rw_deg_per_sqrt_min: float = Field(1.0, ge=0, le=60, description=(
        "after t minutes the heading error's std is this * sqrt(t) degrees"))
    scale_std: float = Field(0.01, ge=0, lt=0.5, description=(
        "std of each robot's distance scale error (0.01: 1 % of the distance driven)"))


_MapSpan = Annotated[float, _rule_of(MapperParams, "kappa")]


class KappaConfig(_Finite):
    """Seconds of sightings a map holds, per odometry. The paper sets kappa by how fast drift
    accumulates: here the longest span, in steps of 30 s, over which the odometry misplaces a
    landmark by at most half of CLIPPER's epsilon of 0.25 m (RMS over robots, times and seeds
    0-2 of data set 6, `mrclam.map_drift`, printed by scripts/mrclam_drift.py), so that the
    distance between two landmarks of one map stays within epsilon. VIO-like drift allows
    150 s (0.116 m); dead reckoning misplaces a landmark by 0.27 m in 5 s already, so no span
    keeps its maps consistent and it keeps the paper's 20 s. A number sets both."""

    raw: _MapSpan = Field(20.0, description="s, with dead-reckoned odometry")
    vio: _MapSpan = Field(150.0, description="s, with VIO-like odometry")

    @model_validator(mode="before")
    @classmethod
    def _one_number(cls, value: Any) -> Any:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return {"raw": value, "vio": value}
        return value


class MrclamConfig(_Finite):
    """An evaluation on a UTIAS MRCLAM data set: how its sightings become maps and which
    methods align them. Robots, landmarks and truth come from the data set's folder."""

    description: str = ""
    odometry: Literal["raw", "vio"] = Field("vio", description=(
        "raw: dead-reckoned commanded velocities; vio: the truth with VIO-like drift"))
    vio: VioDriftConfig = VioDriftConfig()
    kappa: KappaConfig = Field(KappaConfig(), description=(
        "s; a map holds the landmarks sighted this recently, per odometry (raw, vio)"))
    nu: Annotated[int, _rule_of(MapperParams, "nu")] = Field(
        1, description="sightings within kappa before a landmark enters the map")
    min_shared: int = Field(3, ge=1, description="landmarks two maps must share to overlap")
    window: Annotated[int | None, _rule_of(TCAFFParams, "window")] = Field(
        None, description="TCAFF window W of every TCAFF method; None: each preset's")
    graph_drift: GraphDrift = Field(
        None, description="iSAM2 between-step drift (m, deg) per 1 Hz step; None: TCAFF's Q")
    duration: float | None = Field(None, gt=0, description="s of data to use (default: all)")
    methods: str | MethodsConfig = "default"

    def kappa_of(self, odometry: str) -> float:
        """s of sightings a map holds with this odometry ("raw" or "vio")."""
        if odometry not in ("raw", "vio"):
            raise ConfigError(f"odometry: expected 'raw' or 'vio', got {odometry!r}")
        return getattr(self.kappa, odometry)


class RgbdConfig(_Finite):
    """An evaluation on recorded RGB-D sequences (7-Scenes or TUM RGB-D folders): how their
    frames become robots' maps and which methods align them. Robots, frames and truth come
    from the folders and the command line."""

    description: str = ""
    odometry: Literal["exact", "vio"] = Field("vio", description=(
        "exact: the sequence's poses; vio: the poses with VIO-like drift"))
    vio: VioDriftConfig = VioDriftConfig()
    kappa: _MapSpan = Field(20.0, description=(
        "s; a map holds the objects seen this recently (the paper's 20 s)"))
    nu: Annotated[int, _rule_of(MapperParams, "nu")] = Field(
        3, description="sightings before an object enters the map")
    min_shared: int = Field(5, ge=1, description=(
        "objects two maps must share under the truth to overlap"))
    match_radius: float = Field(0.3, gt=0, description=(
        "m; two objects share a place under the truth when they are mutual nearest "
        "neighbours this close in the plane"))
    tight: ThresholdConfig = Field(ThresholdConfig(translation=0.3, heading_deg=3.0),
                                   description="a second, tighter false-accept threshold")
    window: Annotated[int | None, _rule_of(TCAFFParams, "window")] = Field(
        None, description="TCAFF window W of every TCAFF method; None: each preset's")
    graph_drift: GraphDrift = Field(
        None, description="iSAM2 between-step drift (m, deg) per 1 Hz step; None: TCAFF's Q")
    methods: str | MethodsConfig = "default"
