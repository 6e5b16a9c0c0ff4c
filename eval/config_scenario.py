"""Scenario configuration (`config`): one simulated world and its robots — the layouts
(indoor return, outdoor path, room, grid), odometry drift, the object-level sensor or the
rendered RGB-D camera, the object mapper, and the people to detect and track.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, Field, field_validator, model_validator
from tcaff_gtsam.mapping.mapper import MapperParams

from tcaff_gtsam.params import TCAFFParams

from .config_base import FILE_NAME, GraphDrift, _Finite, _params, _rule_of
from .sim.maps import MAX_OBJECTS
from .tracker import TrackerParams

#: the longest scenario, s (`ScenarioConfig.duration`, a study's durations, the times of a
#: layout, a written Kimera-like sequence): two hours
MAX_DURATION = 7200.0

#: the widest and tallest rendered image, pixels (`CameraConfig`, a written sequence)
MAX_IMAGE_SIDE = 4096

#: the fastest robot, m/s: its loops round a small room over MAX_DURATION make at most a few
#: million waypoints (`sim.motion.MAX_WAYPOINTS`)
MAX_SPEED = 20.0

#: the longest side of a room, an outdoor path or a separation, a sensor's range and noise,
#: and the most false detections per frame a sensor makes on average
MAX_METRES = 10_000.0
MAX_FALSE_PER_FRAME = 100.0


class OdometryDrift(_Finite):
    """VIO-like drift: random walks of the odometry heading and position."""

    heading_rw_deg: float = Field(0.05, ge=0, le=10, description="deg per sqrt(s)")
    position_rw: float = Field(0.01, ge=0, le=1, description="m per sqrt(s), per axis")


class _Detector(_Finite):
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
    range_min: float = Field(0.3, ge=0, le=MAX_METRES, description="m")
    range_max: float = Field(6.0, gt=0, le=MAX_METRES, description="m")
    p_detect: float = Field(0.8, gt=0, le=1, description="chance to detect a visible object")
    centroid_noise: float = Field(0.05, ge=0, le=MAX_METRES,
                                  description="m, std per axis at zero range")
    centroid_noise_per_m: float = Field(0.01, ge=0, le=MAX_METRES,
                                        description="m of std per m of range")
    size_noise: float = Field(0.1, ge=0, le=1, description="relative std of width and height")
    partial_view: float = Field(0.6, gt=0, le=1,
                                description="smallest share of an extent a view shows")
    false_per_frame: float = Field(0.2, ge=0, le=MAX_FALSE_PER_FRAME,
                                   description="mean false segments per frame")


class CameraConfig(_Finite):
    """A rendered RGB-D camera: when a scenario has one, every frame is ray-cast and mapped by
    the real front end (depth segmenter, lifting, tracker) instead of the object-level sensor."""

    width: int = Field(320, ge=32, le=MAX_IMAGE_SIDE, description="pixels")
    height: int = Field(240, ge=32, le=MAX_IMAGE_SIDE, description="pixels")
    hfov_deg: float = Field(87.0, gt=10, lt=170, description="horizontal field of view")
    mount_height: float = Field(0.6, gt=0, le=MAX_METRES, description="m above the floor")
    pitch_deg: float = Field(5.0, ge=-45, le=45, description="deg looking down")
    depth_noise: float = Field(0.0025, ge=0, le=0.1,
                               description="m of depth std at 1 m; grows with range squared")
    depth_max: float = Field(6.0, gt=0.5, le=MAX_METRES, description="m, farthest depth return")
    clearance: float = Field(0.4, ge=0, le=MAX_METRES, description=(
        "m; objects closer than this to a robot's path are left out so no camera enters one"))


class MappingConfig(_Finite):
    """The object mapper each robot runs, and the window of recent objects it shares."""

    nu: Annotated[int, _rule_of(MapperParams, "nu")] = Field(
        MapperParams.nu, description="sightings before an object enters the map")
    kappa: Annotated[float, _rule_of(MapperParams, "kappa")] = Field(
        MapperParams.kappa, description="s; objects unseen longer leave the map, and only "
                                        "objects seen within kappa are aligned")
    frame_rate: float = Field(10.0, ge=1, le=100,
                              description="Hz of detections, at least the 1 Hz map exchange")


class IndoorReturnLayout(_Finite):
    """Two robots in a square room of boxes; robot 1 leaves for another room and comes back."""

    kind: Literal["indoor_return"]
    room: float = Field(10.0, gt=2, le=MAX_METRES, description="m, side of the room")
    boxes: int = Field(14, ge=3, le=MAX_OBJECTS)
    away_boxes: int = Field(14, ge=0, le=MAX_OBJECTS,
                            description="boxes in the room robot 1 visits")
    away_similarity: float = Field(0.5, ge=0, le=1, description=(
        "share of the away room's boxes laid out like the home room's, 0.3 m jitter"))
    leave_at: float = Field(70.0, ge=0, le=MAX_DURATION, description="s")
    return_at: float = Field(190.0, ge=0, le=MAX_DURATION, description="s, back in the room")
    speed: float = Field(0.5, gt=0, le=MAX_SPEED, description="m/s")

    @model_validator(mode="after")
    def _order(self) -> IndoorReturnLayout:
        if self.return_at <= self.leave_at:
            raise ValueError(f"return_at ({self.return_at}) must be after leave_at "
                             f"({self.leave_at})")
        return self


class PathLayout(_Finite):
    """Two robots on an outdoor path lined with trees, poles, signs, cars, rocks and benches.

    same_direction: robot 1 follows robot 0 `separation` metres behind. opposite_directions:
    they start `separation` metres apart, drive towards each other and cross.
    """

    kind: Literal["same_direction", "opposite_directions"]
    length: float = Field(200.0, gt=10, le=MAX_METRES, description="m")
    objects_per_100m: float = Field(40.0, gt=0, description=(
        "on both sides together; at most MAX_OBJECTS along the whole path"))
    lateral: tuple[float, float] = Field((2.0, 9.0), description="m, from the path's centre")
    separation: float = Field(15.0, gt=0, le=MAX_METRES, description="m")
    speed: float = Field(1.2, gt=0, le=MAX_SPEED, description="m/s")

    @model_validator(mode="after")
    def _fits(self) -> PathLayout:
        if self.separation >= self.length:
            raise ValueError(f"separation ({self.separation}) must be shorter than the path "
                             f"({self.length})")
        if self.objects_per_100m * self.length / 100 > MAX_OBJECTS:
            raise ValueError(f"objects_per_100m ({self.objects_per_100m}) on the "
                             f"{self.length} m path is more than MAX_OBJECTS = {MAX_OBJECTS}")
        return self

    @field_validator("lateral")
    @classmethod
    def _lateral(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not 0 <= value[0] < value[1]:
            raise ValueError(f"need 0 <= near < far, got {value}")
        return value


class RoomLayout(_Finite):
    """Several robots looping in one room of boxes and furniture."""

    kind: Literal["room"]
    room: float = Field(14.0, gt=2, le=MAX_METRES, description="m, side of the room")
    robots: int = Field(4, ge=2, le=8)
    objects: int = Field(24, ge=3, le=MAX_OBJECTS)
    speed: float = Field(0.5, gt=0, le=MAX_SPEED, description="m/s")


class GridLayout(_Finite):
    """A regular grid of identical objects, with a few distinct landmarks around it."""

    kind: Literal["grid"]
    rows: int = Field(5, ge=2, le=100, description="rows x cols at most MAX_OBJECTS")
    cols: int = Field(8, ge=2, le=100)
    spacing: float = Field(2.5, gt=0, le=MAX_METRES, description="m")
    size: float = Field(0.5, gt=0, le=MAX_METRES,
                        description="m, width and height of every grid object")
    holes: float = Field(0.0, ge=0, lt=1, description="share of grid places left empty")
    landmarks: int = Field(0, ge=0, le=MAX_OBJECTS,
                           description="distinct objects placed around the grid")
    formation: Literal["abreast", "opposite"] = Field(
        "abreast", description="abreast: robot 1 sweeps beside robot 0, half a lane over; "
                               "opposite: it starts at the far end and sweeps back")
    speed: float = Field(0.5, gt=0, le=MAX_SPEED, description="m/s")


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
    range_min: float = Field(0.5, ge=0, le=MAX_METRES, description="m")
    range_max: float = Field(8.0, gt=0, le=MAX_METRES, description="m")
    p_detect: float = Field(0.85, gt=0, le=1, description="chance to detect a person in view")
    noise: float = Field(0.1, ge=0, le=MAX_METRES,
                         description="m, position std per axis at zero range")
    noise_per_m: float = Field(0.02, ge=0, le=MAX_METRES, description="m of std per m of range")
    false_per_frame: float = Field(0.3, ge=0, le=MAX_FALSE_PER_FRAME,
                                   description="mean false detections per frame")


_Tracker = _params(TrackerParams)


class PedestriansConfig(_Finite):
    """People walking between random waypoints; every robot detects them, shares its
    detections with its neighbours through each method's frame alignment and tracks them."""

    count: int = Field(6, ge=1, le=200)
    speed: Range = Field((0.5, 1.2), description="m/s, each leg's speed drawn from this range")
    pause: Range = Field((0.0, 3.0), description="s standing at each waypoint")
    margin: float = Field(1.0, ge=0, le=MAX_METRES, description=(
        "m; waypoints lie in the bounding box of the robots' paths grown by this much"))
    rate: float = Field(5.0, gt=0, le=100, description=(
        "Hz of detections and tracking; must divide mapping.frame_rate"))
    detector: PersonDetectorConfig = PersonDetectorConfig()
    tracker: _Tracker = TrackerParams()
    match_distance: float = Field(1.0, gt=0, le=MAX_METRES, description=(
        "m; MOTA counts a track within this distance of a person as tracking them"))
    mota_window: float = Field(10.0, gt=0, le=MAX_DURATION,
                               description="s, the rolling MOTA window")

    @field_validator("speed")
    @classmethod
    def _moving(cls, value: tuple[float, float]) -> tuple[float, float]:
        if value[0] <= 0:
            raise ValueError(f"people must walk: need a lowest speed > 0, got {value}")
        return value


class ScenarioConfig(_Finite):
    """One simulated world, its robots and their sensors."""

    name: str = Field(min_length=1, pattern=FILE_NAME)
    description: str = ""
    duration: float = Field(ge=1, le=MAX_DURATION,
                            description="s, at least one 1 Hz map exchange")
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
