"""YAML configuration of scenarios, method sets and studies, validated with pydantic.

Unknown keys, wrong types and out-of-range values are rejected with a `ConfigError` whose one-line
message names the key's path, for example
`indoor_return.yaml: layout.room: Input should be greater than 0 (got -1)`.

A study names its scenarios and method set either by the name of a file shipped in
`eval/configs/` (`indoor_return`, `default`) or by a path, or holds them inline. The effective
configuration a study writes next to its results has everything inline and loads again as is.

Settings of an algorithm are not mirrored here: a key that holds them is validated by building
the algorithm's parameter dataclass (`FrameAlignerParams`, `TCAFFParams`, `GraphParams`,
`TrackerParams`; `MapperParams` for `mapping.nu` and `mapping.kappa`) from the keys given, so
its defaults and rules are the only ones, and its `ConfigError` comes out with the key's path.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PlainSerializer,
    PlainValidator,
    ValidationError,
    field_validator,
    model_validator,
)
from tcaff_gtsam.mapping.mapper import MapperParams

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.params import (
    FrameAlignerParams,
    GraphParams,
    ParameterError,
    TCAFFParams,
)

from .registry import METHODS
from .tracker import TrackerParams

__all__ = [
    "CONFIG_DIR",
    "KimeraMultiConfig",
    "MethodsConfig",
    "MrclamConfig",
    "RgbdConfig",
    "ScenarioConfig",
    "StudyConfig",
    "SweepConfig",
    "UniqueKeyLoader",
    "apply_settings",
    "load_kimera_multi",
    "load_methods",
    "load_mrclam",
    "load_rgbd",
    "load_scenario",
    "load_study",
    "load_sweep",
    "override",
]

CONFIG_DIR = Path(__file__).parent / "configs"



def _check_drift(value: tuple[float, float] | None) -> tuple[float, float] | None:
    if value is not None and not (value[0] > 0 and value[1] > 0):
        raise ValueError(f"need (metres > 0, degrees > 0), got {value}")
    return value


#: an iSAM2 between-step drift (metres, degrees), or None
GraphDrift = Annotated[tuple[float, float] | None, AfterValidator(_check_drift)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# -- parameter dataclasses as config values ----------------------------------------------------


class _EntryError(ValueError):
    """A bad entry of a mapping a parameter object is built from; `keys` (from the mapping
    down) extend the key path of the error, `value` is the entry's value (None with
    `show_value` False: an unknown key)."""

    def __init__(self, keys: tuple[str, ...], message: str, value: Any = None,
                 show_value: bool = True) -> None:
        super().__init__(f"{'.'.join(keys)}: {message}")
        self.keys, self.message, self.value, self.show_value = keys, message, value, show_value

    def within(self, key: str) -> _EntryError:
        return _EntryError((key, *self.keys), self.message, self.value, self.show_value)


def _build(cls: type, data: Any, fixed: dict[str, str]) -> Any:
    """A `cls` (a frozen parameter dataclass) from a mapping of some of its fields, the rest
    keeping the dataclass's defaults; an instance passes as it is. Fields in `fixed` (name ->
    why) belong to the run, not to this mapping, and are refused unless left at the default."""
    if isinstance(data, cls):
        default = cls()
        for name, why in fixed.items():
            if replace(default, **{name: getattr(data, name)}) != default:
                raise _EntryError((name,), why, getattr(data, name))
        return data
    if not isinstance(data, dict):
        raise ValueError(f"must be a mapping of {cls.__name__} fields")
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    types = typing.get_type_hints(cls)
    kwargs = {}
    for key, value in data.items():
        if key in fixed:
            raise _EntryError((key,), fixed[key], value)
        if key not in names:
            raise _EntryError((str(key),), "Extra inputs are not permitted", show_value=False)
        if dataclasses.is_dataclass(types[key]):
            try:
                value = _build(types[key], value, {})
            except _EntryError as exc:
                raise exc.within(key) from None
            except ValueError as exc:
                raise _EntryError((key,), str(exc), value) from None
        kwargs[key] = value
    try:
        return cls(**kwargs)
    except ParameterError as exc:
        raise _EntryError((exc.name,), exc.rule, exc.value) from None


def _plain(value: Any, skip: tuple[str, ...] = ()) -> Any:
    """`value` as YAML-safe data: dataclasses as mappings of their fields (but `skip`), arrays
    and tuples as lists, numpy scalars as Python numbers."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                if f.init and f.name not in skip}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _params(cls: type, **fixed: str) -> Any:
    """The config type of parameter dataclass `cls`: in YAML a mapping of some of its fields,
    in Python an instance; written out (JSON mode) as the mapping of all its fields but the
    `fixed` ones (name -> why they are set elsewhere), which loads again as the same object."""
    return Annotated[cls, PlainValidator(lambda data: _build(cls, data, fixed)),
                     PlainSerializer(lambda value: _plain(value, tuple(fixed)), when_used="json")]


def _rule_of(cls: type, name: str) -> AfterValidator:
    """Checks a config value (None passes) by the rule of field `name` of `cls`, so that the
    rule is written once, in the dataclass."""

    def check(value: Any) -> Any:
        if value is not None:
            try:
                cls(**{name: value})
            except ParameterError as exc:
                raise ValueError(exc.rule) from None
        return value

    return AfterValidator(check)


# -- scenarios ---------------------------------------------------------------------------------


class OdometryDrift(_Model):
    """VIO-like drift: random walks of the odometry heading and position."""

    heading_rw_deg: float = Field(0.05, ge=0, le=10, description="deg per sqrt(s)")
    position_rw: float = Field(0.01, ge=0, le=1, description="m per sqrt(s), per axis")


class _Detector(_Model):
    """A detector with a field of view between range_min and range_max (set by subclasses)."""

    @model_validator(mode="after")
    def _ranges(self) -> _Detector:
        if self.range_max <= self.range_min:
            raise ValueError(f"range_max ({self.range_max}) must exceed range_min "
                             f"({self.range_min})")
        return self


class SensorConfig(_Detector):
    """Object detections of a forward-looking RGB-D camera after segmentation and lifting."""

    fov_deg: float = Field(90.0, gt=0, le=360)
    range_min: float = Field(0.3, ge=0, description="m")
    range_max: float = Field(6.0, gt=0, description="m")
    p_detect: float = Field(0.8, gt=0, le=1, description="chance to detect a visible object")
    centroid_noise: float = Field(0.05, ge=0, description="m, std per axis at zero range")
    centroid_noise_per_m: float = Field(0.01, ge=0, description="m of std per m of range")
    size_noise: float = Field(0.1, ge=0, le=1, description="relative std of width and height")
    partial_view: float = Field(0.6, gt=0, le=1,
                                description="smallest share of an extent a view shows")
    false_per_frame: float = Field(0.2, ge=0, description="mean false segments per frame")


class CameraConfig(_Model):
    """A rendered RGB-D camera: when a scenario has one, every frame is ray-cast and mapped by
    the real front end (depth segmenter, lifting, tracker) instead of the object-level sensor."""

    width: int = Field(320, ge=32, le=4096, description="pixels")
    height: int = Field(240, ge=32, le=4096, description="pixels")
    hfov_deg: float = Field(87.0, gt=10, lt=170, description="horizontal field of view")
    mount_height: float = Field(0.6, gt=0, description="m above the floor")
    pitch_deg: float = Field(5.0, ge=-45, le=45, description="deg looking down")
    depth_noise: float = Field(0.0025, ge=0, le=0.1,
                               description="m of depth std at 1 m; grows with range squared")
    depth_max: float = Field(6.0, gt=0.5, description="m, farthest depth return")
    clearance: float = Field(0.4, ge=0, description=(
        "m; objects closer than this to a robot's path are left out so no camera enters one"))


class MappingConfig(_Model):
    """The object mapper each robot runs, and the window of recent objects it shares."""

    nu: Annotated[int, _rule_of(MapperParams, "nu")] = Field(
        MapperParams.nu, description="sightings before an object enters the map")
    kappa: Annotated[float, _rule_of(MapperParams, "kappa")] = Field(
        MapperParams.kappa, description="s; objects unseen longer leave the map, and only "
                                        "objects seen within kappa are aligned")
    frame_rate: float = Field(10.0, ge=1, le=100,
                              description="Hz of detections, at least the 1 Hz map exchange")


class IndoorReturnLayout(_Model):
    """Two robots in a square room of boxes; robot 1 leaves for another room and comes back."""

    kind: Literal["indoor_return"]
    room: float = Field(10.0, gt=2, description="m, side of the room")
    boxes: int = Field(14, ge=3)
    away_boxes: int = Field(14, ge=0, description="boxes in the room robot 1 visits")
    away_similarity: float = Field(0.5, ge=0, le=1, description=(
        "share of the away room's boxes laid out like the home room's, 0.3 m jitter"))
    leave_at: float = Field(70.0, ge=0, description="s")
    return_at: float = Field(190.0, ge=0, description="s, back in the room")
    speed: float = Field(0.5, gt=0, description="m/s")

    @model_validator(mode="after")
    def _order(self) -> IndoorReturnLayout:
        if self.return_at <= self.leave_at:
            raise ValueError(f"return_at ({self.return_at}) must be after leave_at "
                             f"({self.leave_at})")
        return self


class PathLayout(_Model):
    """Two robots on an outdoor path lined with trees, poles, signs, cars, rocks and benches.

    same_direction: robot 1 follows robot 0 `separation` metres behind. opposite_directions:
    they start `separation` metres apart, drive towards each other and cross.
    """

    kind: Literal["same_direction", "opposite_directions"]
    length: float = Field(200.0, gt=10, description="m")
    objects_per_100m: float = Field(40.0, gt=0, description="on both sides together")
    lateral: tuple[float, float] = Field((2.0, 9.0), description="m, from the path's centre")
    separation: float = Field(15.0, gt=0, description="m")
    speed: float = Field(1.2, gt=0, description="m/s")

    @model_validator(mode="after")
    def _fits(self) -> PathLayout:
        if self.separation >= self.length:
            raise ValueError(f"separation ({self.separation}) must be shorter than the path "
                             f"({self.length})")
        return self

    @field_validator("lateral")
    @classmethod
    def _lateral(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not 0 <= value[0] < value[1]:
            raise ValueError(f"need 0 <= near < far, got {value}")
        return value


class RoomLayout(_Model):
    """Several robots looping in one room of boxes and furniture."""

    kind: Literal["room"]
    room: float = Field(14.0, gt=2, description="m, side of the room")
    robots: int = Field(4, ge=2, le=8)
    objects: int = Field(24, ge=3)
    speed: float = Field(0.5, gt=0, description="m/s")


class GridLayout(_Model):
    """A regular grid of identical objects, with a few distinct landmarks around it."""

    kind: Literal["grid"]
    rows: int = Field(5, ge=2)
    cols: int = Field(8, ge=2)
    spacing: float = Field(2.5, gt=0, description="m")
    size: float = Field(0.5, gt=0, description="m, width and height of every grid object")
    holes: float = Field(0.0, ge=0, lt=1, description="share of grid places left empty")
    landmarks: int = Field(0, ge=0, description="distinct objects placed around the grid")
    formation: Literal["abreast", "opposite"] = Field(
        "abreast", description="abreast: robot 1 sweeps beside robot 0, half a lane over; "
                               "opposite: it starts at the far end and sweeps back")
    speed: float = Field(0.5, gt=0, description="m/s")


Layout = Annotated[IndoorReturnLayout | PathLayout | RoomLayout | GridLayout,
                   Field(discriminator="kind")]


def _check_range(value: tuple[float, float]) -> tuple[float, float]:
    if not 0 <= value[0] <= value[1]:
        raise ValueError(f"need 0 <= low <= high, got {value}")
    return value


#: a (low, high) range of non-negative numbers
Range = Annotated[tuple[float, float], AfterValidator(_check_range)]


class PersonDetectorConfig(_Detector):
    """A person detector on each robot: people in its field of view and range, each found with
    some probability, placed with noise that grows with range, plus false detections."""

    fov_deg: float = Field(90.0, gt=0, le=360)
    range_min: float = Field(0.5, ge=0, description="m")
    range_max: float = Field(8.0, gt=0, description="m")
    p_detect: float = Field(0.85, gt=0, le=1, description="chance to detect a person in view")
    noise: float = Field(0.1, ge=0, description="m, position std per axis at zero range")
    noise_per_m: float = Field(0.02, ge=0, description="m of std per m of range")
    false_per_frame: float = Field(0.3, ge=0, description="mean false detections per frame")


_Tracker = _params(TrackerParams)


class PedestriansConfig(_Model):
    """People walking between random waypoints; every robot detects them, shares its
    detections with its neighbours through each method's frame alignment and tracks them."""

    count: int = Field(6, ge=1, le=200)
    speed: Range = Field((0.5, 1.2), description="m/s, each leg's speed drawn from this range")
    pause: Range = Field((0.0, 3.0), description="s standing at each waypoint")
    margin: float = Field(1.0, ge=0, description=(
        "m; waypoints lie in the bounding box of the robots' paths grown by this much"))
    rate: float = Field(5.0, gt=0, le=100, description=(
        "Hz of detections and tracking; must divide mapping.frame_rate"))
    detector: PersonDetectorConfig = PersonDetectorConfig()
    tracker: _Tracker = TrackerParams()
    match_distance: float = Field(1.0, gt=0, description=(
        "m; MOTA counts a track within this distance of a person as tracking them"))
    mota_window: float = Field(10.0, gt=0, description="s, the rolling MOTA window")

    @field_validator("speed")
    @classmethod
    def _moving(cls, value: tuple[float, float]) -> tuple[float, float]:
        if value[0] <= 0:
            raise ValueError(f"people must walk: need a lowest speed > 0, got {value}")
        return value


class ScenarioConfig(_Model):
    """One simulated world, its robots and their sensors."""

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    duration: float = Field(ge=1, le=7200, description="s, at least one 1 Hz map exchange")
    layout: Layout
    odometry: OdometryDrift | list[OdometryDrift] = OdometryDrift()
    sensor: SensorConfig = SensorConfig()
    camera: CameraConfig | None = Field(None, description=(
        "render RGB-D and map it with the real front end; `sensor` is then unused"))
    mapping: MappingConfig = MappingConfig()
    window: Annotated[int | None, _rule_of(TCAFFParams, "window")] = Field(
        None, description="TCAFF window W of every TCAFF method; None: each preset's")
    graph_drift: GraphDrift = Field(
        None, description="(m, deg) per step: the alignment drift the iSAM2 graph assumes; "
                          "None: TCAFF's Q")
    min_shared: int = Field(5, ge=1, description="objects two maps must share to overlap")
    pedestrians: PedestriansConfig | None = Field(None, description=(
        "people to detect and track together (multi-object tracking, MOTA); None: no people"))

    @property
    def n_robots(self) -> int:
        return self.layout.robots if isinstance(self.layout, RoomLayout) else 2

    def drift(self, robot: int) -> OdometryDrift:
        """The odometry drift of one robot."""
        return self.odometry[robot] if isinstance(self.odometry, list) else self.odometry

    @model_validator(mode="after")
    def _per_robot(self) -> ScenarioConfig:
        if isinstance(self.odometry, list) and len(self.odometry) != self.n_robots:
            raise ValueError(f"odometry: a list needs one entry per robot ({self.n_robots}), "
                             f"got {len(self.odometry)}")
        return self

    @model_validator(mode="after")
    def _people_frames(self) -> ScenarioConfig:
        if self.pedestrians is None:
            return self
        every = self.mapping.frame_rate / self.pedestrians.rate
        if abs(every - round(every)) > 1e-9 or round(every) < 1:
            raise ValueError(f"pedestrians.rate ({self.pedestrians.rate} Hz) must divide "
                             f"mapping.frame_rate ({self.mapping.frame_rate} Hz)")
        return self


# -- methods -----------------------------------------------------------------------------------


class IcpConfig(_Model):
    """ICP on object centroids, started from the true alignment, then from its last estimate."""

    max_correspondence_distance: float = Field(1.0, gt=0, description="m")
    min_correspondences: int = Field(5, ge=3)
    max_iterations: int = Field(30, ge=1)


class ThresholdConfig(_Model):
    """An estimate further from the truth than either threshold is a false accept."""

    translation: float = Field(1.0, gt=0, description="m")
    heading_deg: float = Field(5.0, gt=0, le=180)


_PER_RUN = "is set per scenario/data set ({}), not per method set"
_Aligner = _params(FrameAlignerParams, kappa=_PER_RUN.format("mapping.kappa"))
_Tcaff = _params(TCAFFParams, window="the TCAFF window W " + _PER_RUN.format("window"))
_Graph = _params(GraphParams, Q="the alignment drift " + _PER_RUN.format("graph_drift"),
                 dim="the compared methods align planar frames: dim is 2")


class MethodsConfig(_Model):
    """Which methods a study compares, and their settings.

    `aligner` (the FrameAligner of the TCAFF methods), `tcaff` (the default TCAFF preset;
    `tcaff_reference` is always the released code's) and `graph` (the iSAM2 graph) take any
    fields of their parameter dataclass; the rest keep its defaults. What belongs to the run is
    set by the scenario or data set and refused here: kappa (`mapping.kappa`), the window W
    (`window`) and the graph's drift (`graph_drift`).
    """

    name: str = Field("methods", min_length=1)
    methods: list[str] = Field(default_factory=lambda: list(METHODS), min_length=1,
                               description="names in the registry (registry.METHODS)")
    clipper_k: list[int] = Field(default_factory=lambda: list(range(3, 13)), min_length=1)
    clipper_k_shown: int = Field(10, description="the single-shot threshold drawn over time")
    aligner: _Aligner = FrameAlignerParams()
    tcaff: _Tcaff = TCAFFParams()
    icp: IcpConfig = IcpConfig()
    graph: _Graph = GraphParams()
    thresholds: ThresholdConfig = ThresholdConfig()

    def aligner_params(self, kappa: float) -> FrameAlignerParams:
        """The FrameAligner of the TCAFF methods, objects seen within `kappa` s (the run's)."""
        return replace(self.aligner, kappa=kappa)

    def tcaff_params(self, reference: bool, window: int | None) -> TCAFFParams:
        """This set's TCAFF preset, or (`reference`) the released code's settings as they are,
        with the run's window W (None: the preset's)."""
        base = TCAFFParams.reference() if reference else self.tcaff
        return base if window is None else replace(base, window=window)

    def graph_params(self, drift: tuple[float, float] | None) -> GraphParams:
        """This set's iSAM2 graph, assuming `drift` (metres, degrees) of alignment drift per
        step (None: TCAFF's Q)."""
        if drift is None:
            return self.graph
        metres, degrees = drift
        Q = np.diag([metres**2, metres**2, np.radians(degrees) ** 2])
        return replace(self.graph, Q=Q)

    @field_validator("methods")
    @classmethod
    def _unique(cls, value: list[str]) -> list[str]:
        unknown = [m for m in value if m not in METHODS]
        if unknown:
            raise ValueError(f"unknown methods {unknown}; registered: {', '.join(METHODS)}")
        if len(set(value)) != len(value):
            raise ValueError(f"methods must not repeat, got {value}")
        return value

    @field_validator("clipper_k")
    @classmethod
    def _k(cls, value: list[int]) -> list[int]:
        if any(k < 2 for k in value) or len(set(value)) != len(value):
            raise ValueError(f"clipper_k must be distinct ints >= 2, got {value}")
        return sorted(value)

    @model_validator(mode="after")
    def _shown(self) -> MethodsConfig:
        if "clipper" in self.methods and self.clipper_k_shown not in self.clipper_k:
            raise ValueError(f"clipper_k_shown ({self.clipper_k_shown}) must be one of "
                             f"clipper_k {self.clipper_k}")
        return self


# -- studies -----------------------------------------------------------------------------------


class StudyConfig(_Model):
    """Scenarios x methods x seeds."""

    name: str = Field("study", min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    scenarios: list[str | ScenarioConfig] = Field(min_length=1)
    methods: str | MethodsConfig = "default"
    seeds: list[int] = Field(default_factory=lambda: [0], min_length=1)
    workers: int = Field(2, ge=1, le=64)
    output: str = "results"

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, value: list[int]) -> list[int]:
        if any(s < 0 for s in value) or len(set(value)) != len(value):
            raise ValueError(f"seeds must be distinct ints >= 0, got {value}")
        return value


#: where a swept parameter's dotted path points: into the method set, or into every scenario
SWEEP_ROOTS = ("methods", "scenario")


class SweepConfig(_Model):
    """A base study run at several parameter points.

    A parameter is a dotted path into the method set (`methods.tcaff.tau`) or into every
    scenario of the study (`scenario.window`, `scenario.mapping.kappa`). `grid` runs every
    combination of its values; `points` lists the points one by one (each setting the same
    parameters). The study as given (no parameter changed) is the default point.
    """

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    study: str | StudyConfig = Field(description="the base study: shipped name, path or inline")
    grid: dict[str, list[Any]] | None = Field(None, description="path -> values, every combination")
    points: list[dict[str, Any]] | None = Field(None, description="path -> value, one per point")
    seeds: list[int] | None = Field(None, min_length=1, description="default: the study's")
    method: str = Field("tcaff", description="the estimate the report's table and figures show")
    output: str = Field("results/sweeps", description="results go to OUTPUT/<name>/")

    @field_validator("grid")
    @classmethod
    def _grid(cls, value: dict[str, list[Any]] | None) -> dict[str, list[Any]] | None:
        if value is None:
            return value
        if not value:
            raise ValueError("needs at least one parameter path")
        for path, values in value.items():
            _check_sweep_path(path)
            if not values:
                raise ValueError(f"{path}: needs at least one value")
            if len({repr(v) for v in values}) != len(values):
                raise ValueError(f"{path}: values must not repeat, got {values}")
        return value

    @field_validator("points")
    @classmethod
    def _points(cls, value: list[dict[str, Any]] | None) -> list[dict[str, Any]] | None:
        if value is None:
            return value
        if not value:
            raise ValueError("needs at least one point")
        for k, point in enumerate(value):
            if not point:
                raise ValueError(f"point {k} sets no parameter")
            for path in point:
                _check_sweep_path(path)
            if set(point) != set(value[0]):
                raise ValueError(f"point {k} sets {sorted(point)}; every point must set the "
                                 f"first one's {sorted(value[0])}")
        return value

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, value: list[int] | None) -> list[int] | None:
        if value is not None and (any(s < 0 for s in value) or len(set(value)) != len(value)):
            raise ValueError(f"seeds must be distinct ints >= 0, got {value}")
        return value

    @model_validator(mode="after")
    def _one_way(self) -> SweepConfig:
        if (self.grid is None) == (self.points is None):
            raise ValueError("give either grid (every combination) or points (a list)")
        return self

    @property
    def parameters(self) -> list[str]:
        """The swept paths, in the file's order."""
        return list(self.grid if self.grid is not None else self.points[0])  # type: ignore[index]


def _check_sweep_path(path: str) -> None:
    root, _, rest = path.partition(".")
    if root not in SWEEP_ROOTS or not rest or not all(path.split(".")):
        raise ValueError(f"{path}: a parameter path is methods.<key>[.<key>...] or "
                         f"scenario.<key>[.<key>...]")


class ExtrinsicsConfig(_Model):
    """A sensor frame in a parent frame: `xyz` metres, then `rpy_deg` (roll, pitch, yaw about
    the parent's fixed x, y, z axes, ROS order). `matrix` (16 numbers, row-major 4 x 4) replaces
    both when given."""

    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    matrix: list[float] | None = Field(None, min_length=16, max_length=16)


class RgbdRigConfig(_Model):
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


class TopicsConfig(_Model):
    """Topic names of one robot; `{robot}` is replaced by its name."""

    color: str = "/{robot}/forward/color/image_raw/compressed"
    color_info: str = "/{robot}/forward/color/camera_info"
    depth: str = "/{robot}/forward/depth/image_rect_raw"
    depth_info: str = "/{robot}/forward/depth/camera_info"
    odometry: str = "/{robot}/jackal_velocity_controller/odom"

    def of(self, robot: str) -> dict[str, str]:
        """Role -> topic name for `robot`."""
        return {role: topic.replace("{robot}", robot) for role, topic in self}


class KimeraMultiConfig(_Model):
    """One Kimera-Multi test: which robots' bags to map and align, and how."""

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
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
        if len(set(value)) != len(value) or not all(value):
            raise ValueError(f"robots must be distinct non-empty names, got {value}")
        return value


class VioDriftConfig(_Model):
    """Visual-inertial-like odometry made from the true poses: the heading takes a random walk
    and every distance driven is scaled by (1 + e), e drawn once per robot."""

    heading_rw_deg_per_sqrt_min: float = Field(1.0, ge=0, le=60, description=(
        "after t minutes the heading error's std is this * sqrt(t) degrees"))
    scale_std: float = Field(0.01, ge=0, lt=0.5, description=(
        "std of each robot's distance scale error (0.01: 1 % of the distance driven)"))


_MapSpan = Annotated[float, _rule_of(MapperParams, "kappa")]


class KappaConfig(_Model):
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


class MrclamConfig(_Model):
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


class RgbdConfig(_Model):
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


# -- loading -----------------------------------------------------------------------------------


_LAYOUT_KINDS = ("indoor_return", "same_direction", "opposite_directions", "room", "grid")


def _path(loc: tuple) -> str:
    """The key path of a pydantic error location, without union-branch and validator tags."""
    parts: list[str] = []
    for k, item in enumerate(loc):
        item = str(item)
        if (item.startswith("function-") or "[" in item or item[:1].isupper()
                or item == "str" or (item in _LAYOUT_KINDS and k and loc[k - 1] == "layout")):
            continue
        parts.append(item)
    return ".".join(parts) or "(top level)"


def _format(source: str, error: ValidationError) -> str:
    items = error.errors()
    # a name-or-inline field fails as a string too; that branch's complaint is noise
    detailed = [e for e in items if not (e["type"] == "string_type" and "str" in e["loc"])]
    parts = []
    for item in detailed or items:
        path, value = _path(item["loc"]), item.get("input")
        message = item["msg"].removeprefix("Value error, ")
        show = item["type"] not in ("missing", "extra_forbidden") and not isinstance(value, dict)
        entry = item.get("ctx", {}).get("error")
        if isinstance(entry, _EntryError):
            # after _path, which drops capitalised parts (union tags) and fields such as Q
            path = ".".join([*(p for p in [path] if p != "(top level)"), *entry.keys])
            message, value, show = entry.message, entry.value, entry.show_value
        if show:
            message += f" (got {value!r})"
        parts.append(f"{path}: {message}")
    return f"{source}: " + "; ".join(dict.fromkeys(parts))


class _DuplicateKeyError(yaml.constructor.ConstructorError):
    """A key given twice in one YAML mapping."""

    def __init__(self, key: Any, mark: yaml.Mark | None) -> None:
        super().__init__(problem=f"duplicate key {key!r}", problem_mark=mark)
        self.key, self.line = key, None if mark is None else mark.line + 1


class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (the plain loader keeps
    the last value silently). Keys brought in by a merge (`<<: *base`) may be overridden."""

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict:
        if isinstance(node, yaml.MappingNode):
            seen: set = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    if key in seen:
                        raise _DuplicateKeyError(key, key_node.start_mark)
                    seen.add(key)
                except TypeError:  # unhashable: the safe loader refuses it below
                    continue
        return super().construct_mapping(node, deep)


def _read_yaml(path: Path) -> Any:
    if not path.is_file():
        raise ConfigError(f"{path}: no such config file")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file (byte 0x{exc.object[exc.start]:02x} "
                          f"at offset {exc.start})") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc.strerror})") from None
    try:
        return yaml.load(text, Loader=UniqueKeyLoader)
    except _DuplicateKeyError as exc:
        where = "" if exc.line is None else f" (line {exc.line})"
        raise ConfigError(f"{path}: duplicate key {exc.key!r}{where}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from exc
    except RecursionError:
        raise ConfigError(f"{path}: not valid YAML (nested too deeply)") from None


def _validate(model: type[_Model], data: Any, source: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of keys, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format(source, exc)) from None


def _resolve(ref: str, folder: str) -> Path:
    """A shipped config's name (`indoor_return`) or a path to a YAML file."""
    path = Path(ref)
    if path.suffix in (".yaml", ".yml") or path.parent != Path("."):
        return path
    shipped = CONFIG_DIR / folder / f"{ref}.yaml"
    if not shipped.is_file():
        names = sorted(p.stem for p in (CONFIG_DIR / folder).glob("*.yaml"))
        kind = {"scenarios": "scenario", "methods": "method set", "studies": "study",
                "kimera_multi": "Kimera-Multi test", "mrclam": "MRCLAM evaluation",
                "rgbd": "RGB-D evaluation", "sweeps": "sweep"}[folder]
        raise ConfigError(f"no {kind} config named {ref!r}; shipped: {', '.join(names)}")
    return shipped


def _near(ref: str, folder: Path | None) -> str:
    """`ref`, or the YAML file of that relative path in `folder` (a config's own folder) when
    it is there."""
    path = Path(ref)
    if folder is not None and path.suffix in (".yaml", ".yml") and not path.is_absolute():
        if (folder / path).is_file():
            return str(folder / path)
    return ref


def load_scenario(ref: str | Path) -> ScenarioConfig:
    """A scenario by shipped name or path."""
    path = _resolve(str(ref), "scenarios")
    return _validate(ScenarioConfig, _read_yaml(path), path.name)


def load_methods(ref: str | Path) -> MethodsConfig:
    """A method set by shipped name or path."""
    path = _resolve(str(ref), "methods")
    return _validate(MethodsConfig, _read_yaml(path), path.name)


def load_study(ref: str | Path, overrides: dict[str, Any] | None = None) -> StudyConfig:
    """A study by shipped name or path, with its scenarios and method set loaded inline.

    Args:
        overrides: top-level keys replacing the file's (validated like the file).
    """
    path = _resolve(str(ref), "studies")
    data = _read_yaml(path)
    if overrides and isinstance(data, dict):
        data = {**data, **overrides}
    return resolve_study(_validate(StudyConfig, data, path.name), path.parent)


def load_sweep(ref: str | Path) -> tuple[SweepConfig, StudyConfig]:
    """A sweep by shipped name or path, and its base study resolved (scenarios and method set
    inline, the sweep's seeds when it gives them)."""
    path = _resolve(str(ref), "sweeps")
    sweep = _validate(SweepConfig, _read_yaml(path), path.name)
    if isinstance(sweep.study, StudyConfig):
        study = resolve_study(sweep.study, path.parent)
    else:
        study = load_study(_near(sweep.study, path.parent))
    if sweep.seeds is not None:
        study = study.model_copy(update={"seeds": sweep.seeds})
    return sweep, study


def apply_settings(config: ScenarioConfig | MethodsConfig, settings: dict[str, Any],
                   source: str) -> Any:
    """`config` with some settings changed, validated like a file.

    Args:
        settings: dotted path -> value; the first part of each path (`methods`, `scenario`)
            names the config and is skipped.
        source: names the settings in errors (e.g. "tau_window.yaml").
    Raises:
        ConfigError: a path that `config` does not have, or a value it refuses, naming the
            path and the value.
    """
    data = config.model_dump(mode="json")
    label = ", ".join(f"{path} = {value!r}" for path, value in settings.items())
    for path, value in settings.items():
        keys = path.split(".")[1:]
        node = data
        for depth, key in enumerate(keys[:-1]):
            child = node.get(key) if isinstance(node, dict) else None
            if not isinstance(child, dict):
                what = "has no key" if not isinstance(node, dict) or key not in node else (
                    f"has {key} = {child!r}, nothing to set inside")
                where = getattr(config, "name", type(config).__name__)
                raise ConfigError(f"{source}: {path}: {where} {what} "
                                  f"{'.'.join(keys[:depth + 1])!r}")
            node = child
        node[keys[-1]] = value
    return _validate(type(config), data, f"{source}: {label}")


def resolve_study(study: StudyConfig, folder: Path | None = None) -> StudyConfig:
    """The same study with every scenario and the method set inline; relative YAML paths are
    taken from `folder` (the study file's) when the file is there."""
    scenarios = [s if isinstance(s, ScenarioConfig) else load_scenario(_near(s, folder))
                 for s in study.scenarios]
    names = [s.name for s in scenarios]
    if len(set(names)) != len(names):
        raise ConfigError(f"study {study.name}: scenario names must be distinct, got {names}")
    methods = (study.methods if isinstance(study.methods, MethodsConfig)
               else load_methods(_near(study.methods, folder)))
    return study.model_copy(update={"scenarios": scenarios, "methods": methods})


def _load_with_methods(model: type[_Model], ref: str | Path, folder: str) -> Any:
    path = _resolve(str(ref), folder)
    config = _validate(model, _read_yaml(path), path.name)
    if isinstance(config.methods, str):
        config = config.model_copy(
            update={"methods": load_methods(_near(config.methods, path.parent))})
    return config


def override(config: _Model, source: str, **updates: Any) -> Any:
    """`config` with some top-level keys replaced (None values are ignored), validated like a
    file; errors name `source` (e.g. "command line")."""
    data = {name: getattr(config, name) for name in type(config).model_fields}
    data.update({k: v for k, v in updates.items() if v is not None})
    return _validate(type(config), data, source)


def load_kimera_multi(ref: str | Path) -> KimeraMultiConfig:
    """A Kimera-Multi test by shipped name (`same_direction`) or path, its method set loaded
    inline."""
    return _load_with_methods(KimeraMultiConfig, ref, "kimera_multi")


def load_mrclam(ref: str | Path) -> MrclamConfig:
    """An MRCLAM evaluation by shipped name (`default`) or path, its method set loaded
    inline."""
    return _load_with_methods(MrclamConfig, ref, "mrclam")


def load_rgbd(ref: str | Path) -> RgbdConfig:
    """An RGB-D sequence evaluation by shipped name (`default`) or path, its method set loaded
    inline."""
    return _load_with_methods(RgbdConfig, ref, "rgbd")


def dump_study(study: StudyConfig) -> str:
    """YAML of a resolved study, loadable again with `load_study`."""
    return yaml.safe_dump(study.model_dump(mode="json"), sort_keys=False)

