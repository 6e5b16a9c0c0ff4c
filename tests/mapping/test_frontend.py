"""Tests for tcaff_gtsam.mapping.frontend: the RGB-D front end driven over rendered trajectories
(the issue's acceptance: one map object per real object, in the odometry frame), depth
registration from a second camera, stage timings and input checks."""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field

import cv2
import numpy as np
import pytest
from rgbd_scenes import SMALL_CAMERA, T_BC, free_pose, majority_instance, random_room
from tcaff_gtsam.eval.sim.render import RgbdScene, render
from tcaff_gtsam.eval.sim.world import room_walls
from tcaff_gtsam.mapping.camera import PinholeCamera, register_depth
from tcaff_gtsam.mapping.frontend import DepthRegistration, FrameResult, RgbdFrontEnd
from tcaff_gtsam.mapping.segment import MaskFilter, depth_border

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import invert, se3_from_xyz_yaw, transform_points

CAM = SMALL_CAMERA  # 320 x 240, 87 deg
DT = 0.1  # 10 Hz
STAGES = {"register", "segment", "filter", "lift", "track"}
#: odometry frame = this fixed transform of the world frame (odometry without drift)
T_ODOM_WORLD = se3_from_xyz_yaw(1.0, -2.0, 0.3, 0.7)


def ring_room() -> RgbdScene:
    """Eight boxes and cylinders around a 10 x 8 m room, >= 1 m from each other and from the
    walls, all taller than the camera."""
    xy = [[1.6, 1.6], [5.0, 1.3], [8.4, 1.7], [8.7, 4.0], [8.3, 6.4], [5.0, 6.7], [1.7, 6.3],
          [1.3, 4.0]]
    widths = [0.5, 0.4, 0.6, 0.45, 0.5, 0.55, 0.4, 0.5]
    heights = [0.9, 1.2, 0.8, 1.0, 1.3, 0.75, 1.1, 0.95]
    cylinders = [False, True, False, True, False, True, False, True]
    yaws = [0.3, 0.0, 0.8, 0.0, 0.1, 0.0, 1.2, 0.0]
    return RgbdScene(xy, widths, heights, cylinders, yaws, walls=room_walls(0, 0, 10, 8))


def loop_poses(n: int, centre=(5.0, 4.0), radius: float = 1.5, period: float = 12.0,
               ) -> list[np.ndarray]:
    """T_world_body of a robot driving counter-clockwise around a circle, one per frame."""
    out = []
    for i in range(n):
        a = 2 * math.pi * i * DT / period
        out.append(se3_from_xyz_yaw(centre[0] + radius * math.cos(a),
                                    centre[1] + radius * math.sin(a), 0.0, a + math.pi / 2))
    return out


def spin_poses(n: int, x: float, y: float, yaw0: float) -> list[np.ndarray]:
    """A robot turning on the spot (on a 0.2 m circle) two full turns."""
    out = []
    for i in range(n):
        a = yaw0 + 4 * math.pi * i / n
        out.append(se3_from_xyz_yaw(x + 0.2 * math.cos(a), y + 0.2 * math.sin(a), 0.0, a))
    return out


class GroundTruthSegmenter:
    """Masks of the ground-truth instances of the frame set in `instance`."""

    instance: np.ndarray | None = None

    def segment(self, rgb, depth):
        ids = np.unique(self.instance)
        return self.instance[None] == ids[ids > 0][:, None, None]


@dataclass
class Run:
    front: RgbdFrontEnd
    scene: RgbdScene
    votes: dict = field(default_factory=lambda: defaultdict(Counter))
    clear_views: Counter = field(default_factory=Counter)  # object -> frames seen unoccluded
    results: list = field(default_factory=list)


def clearly_visible(frame, k: int, mask_filter: MaskFilter, max_range: float = 6.0) -> bool:
    """Object k is wholly in view within `max_range` metres and unoccluded: its pixels pass
    the filter's area and border rules (the band without depth along the edge included) and
    no other object's pixels touch them (an occluder would border its silhouette)."""
    instance = frame.instance
    gt = instance == k + 1
    area = np.count_nonzero(gt)
    if not mask_filter.min_area <= area <= mask_filter.max_area_share * gt.size:
        return False
    if np.median(frame.depth[gt]) > max_range:
        return False
    b = mask_filter.border + 1
    if gt[:b].any() or gt[-b:].any() or gt[:, :b].any() or gt[:, -b:].any():
        return False
    band = depth_border(frame.depth > 0, mask_filter.invalid_margin)
    if np.any(cv2.dilate(band.view(np.uint8), np.ones((2 * b - 1,) * 2, np.uint8)).view(bool)[gt]):
        return False
    ring = cv2.dilate(gt.view(np.uint8), np.ones((5, 5), np.uint8)).view(bool) & ~gt
    return not np.any(instance[ring] > 0)


def drive(scene: RgbdScene, poses: list[np.ndarray], **kwargs) -> Run:
    run = Run(RgbdFrontEnd(CAM, T_BC, depth_scale=1.0, **kwargs), scene)
    for i, T_world_body in enumerate(poses):
        frame = render(scene, T_world_body @ T_BC, CAM)
        result = run.front.process(i * DT, frame.rgb, frame.depth, T_ODOM_WORLD @ T_world_body)
        check_result(result)
        run.results.append(result)
        for mask, track in zip(result.masks, result.track_ids, strict=True):
            run.votes[int(track)][majority_instance(frame.instance, mask)] += 1
        for k in range(len(scene)):
            if clearly_visible(frame, k, run.front.mask_filter):
                run.clear_views[k] += 1
    return run


def check_result(result: FrameResult) -> None:
    k = len(result.observations)
    assert result.masks.shape == (k, *CAM.shape) and result.masks.dtype == np.bool_
    assert result.track_ids.shape == (k,) and result.track_ids.dtype == np.int64
    assert result.observations.centroids.shape == (k, 3)
    assert np.all(result.observations.mask_indices < result.n_masks)
    assert np.unique(result.observations.mask_indices).size == k
    assert set(result.seconds) == STAGES
    assert all(isinstance(s, float) and s >= 0 for s in result.seconds.values())


def check_map(run: Run, min_clear_views: int = 10) -> None:
    scene = run.scene
    ids = run.front.mapper.confirmed_ids()
    om = run.front.object_map()
    assert len(ids) == len(om.centroids) > 0
    labels = []
    for track in ids:
        votes = run.votes[int(track)]
        assert votes, f"confirmed track {track} was never assigned a mask"
        labels.append(votes.most_common(1)[0][0])
    problems = []
    if 0 in labels:
        problems.append(f"map objects on floor or walls: tracks "
                        f"{[int(t) for t, lab in zip(ids, labels, strict=True) if lab == 0]}")
    duplicated = [lab for lab, n in Counter(labels).items() if n > 1 and lab > 0]
    if duplicated:
        problems.append(f"objects mapped more than once: {[lab - 1 for lab in duplicated]}")
    missing = [k for k, n in run.clear_views.items()
               if n >= min_clear_views and k + 1 not in labels]
    if missing:
        problems.append(f"objects seen unoccluded in >= {min_clear_views} frames but not in the "
                        f"map: {missing} (clear views {dict(run.clear_views)})")
    # accuracy, in the world frame
    world = transform_points(invert(T_ODOM_WORLD), om.centroids)
    for lab, c, w, h in zip(labels, world, om.widths, om.heights, strict=True):
        if lab == 0:
            continue
        k = lab - 1
        off = np.hypot(*(c[:2] - scene.xy[k]))
        if off > scene.widths[k] / 2 + 0.05 or abs(c[2] - scene.heights[k] / 2) > 0.15:
            problems.append(f"object {k}: map centroid {np.round(c, 3)} vs centre "
                            f"{scene.xy[k]}, height {scene.heights[k]:.2f}")
        if not (0.75 < w / scene.widths[k] < 1.25 and 0.75 < h / scene.heights[k] < 1.25):
            problems.append(f"object {k}: size {w:.2f} x {h:.2f} vs {scene.widths[k]:.2f} x "
                            f"{scene.heights[k]:.2f}")
    assert not problems, "\n".join(problems)


# ---------------------------------------------------------------------------------------------
# acceptance


@pytest.fixture(scope="module")
def loop_run() -> Run:
    """A loop and a quarter (1.2 m/s, 4.5 deg a frame): the last quarter sees again the
    objects of the first."""
    return drive(ring_room(), loop_poses(100, period=8.0))


def test_loop_maps_each_object_once(loop_run):
    check_map(loop_run)
    # the loop passes every object of the ring
    assert all(loop_run.clear_views[k] >= 10 for k in range(8)), dict(loop_run.clear_views)


def test_loop_map_is_in_the_odometry_frame(loop_run):
    """The map is in the odometry frame: its centroids are the world ones moved by
    T_odom_world, not the world ones."""
    om = loop_run.front.object_map()
    scene = loop_run.scene
    xy_odom = transform_points(T_ODOM_WORLD, np.column_stack([scene.xy, np.zeros(len(scene))]))
    for track, c in zip(loop_run.front.mapper.confirmed_ids(), om.centroids, strict=True):
        k = loop_run.votes[int(track)].most_common(1)[0][0] - 1
        assert k >= 0
        assert np.hypot(*(c[:2] - xy_odom[k, :2])) < 0.5
        assert np.hypot(*(c[:2] - scene.xy[k])) > 1.0
    # the height is along the odometry z axis: z of the offset (0.3 m) added
    assert np.all(om.centroids[:, 2] > 0.3 + 0.3)


@pytest.mark.parametrize("seed", [1, 2])
def test_spinning_in_a_random_room_maps_each_object_once(seed):
    rng = np.random.default_rng(seed)
    scene = random_room(rng, 7, heights=(0.7, 1.4))
    x, y, yaw = free_pose(rng, scene, clearance=1.0)
    check_map(drive(scene, spin_poses(80, x, y, yaw)))  # 9 deg a frame


def test_ground_truth_segmenter_plugs_in():
    """Any object with a segment(rgb, depth) method is a segmenter; with ground-truth masks the
    map holds exactly the objects seen clearly."""

    gt = GroundTruthSegmenter()
    scene = ring_room()
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0, segmenter=gt)
    run = Run(front, scene)
    for i, T_world_body in enumerate(loop_poses(60)):
        frame = render(scene, T_world_body @ T_BC, CAM)
        gt.instance = frame.instance
        result = front.process(i * DT, frame.rgb, frame.depth, T_ODOM_WORLD @ T_world_body)
        check_result(result)
        for mask, track in zip(result.masks, result.track_ids, strict=True):
            run.votes[int(track)][majority_instance(frame.instance, mask)] += 1
            assert np.array_equal(mask, frame.instance == majority_instance(frame.instance,
                                                                             mask))
        for k in range(len(scene)):
            run.clear_views[k] += clearly_visible(frame, k, front.mask_filter)
    check_map(run, min_clear_views=5)


# ---------------------------------------------------------------------------------------------
# depth registration

DEPTH_CAM = PinholeCamera(400, 300, 190.0, 192.0, 203.0, 147.0)  # wider, denser, off-centre
T_COLOR_DEPTH = np.eye(4)
T_COLOR_DEPTH[0, 3] = 0.06  # the depth camera is 6 cm to the right of the colour camera


def registration_errors(depth_camera: PinholeCamera) -> tuple[float, np.ndarray]:
    """Depth rendered by `depth_camera` (6 cm beside the colour camera) registered into the
    colour image: the share of the colour image's returns it covers, and the relative depth
    errors there."""
    scene = ring_room()
    T_wc = loop_poses(30)[10] @ T_BC
    color = render(scene, T_wc, CAM)
    depth = render(scene, T_wc @ T_COLOR_DEPTH, depth_camera)
    registered = register_depth(depth.depth, depth_camera, CAM, T_COLOR_DEPTH)
    both = (registered > 0) & (color.depth > 0)
    rel = np.abs(registered[both] - color.depth[both]) / color.depth[both]
    return both.sum() / np.count_nonzero(color.depth), rel


def test_registered_depth_matches_rendered_depth():
    covered, rel = registration_errors(DEPTH_CAM)
    assert covered > 0.98
    assert np.median(rel) < 0.005
    assert np.mean(rel < 0.03) > 0.97


def test_registration_path_gives_nearly_the_same_observations():
    """Ground-truth masks on both paths, so that only the depth differs."""
    scene = ring_room()
    gt = GroundTruthSegmenter()
    direct = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0, segmenter=gt)
    registered = RgbdFrontEnd(CAM, T_BC, depth_scale=1000.0, segmenter=gt,
                              registration=DepthRegistration(DEPTH_CAM, T_COLOR_DEPTH))
    compared = 0
    for i, T_world_body in enumerate(loop_poses(150)[::10]):
        T_wc = T_world_body @ T_BC
        color = render(scene, T_wc, CAM)
        gt.instance = color.instance
        depth = render(scene, T_wc @ T_COLOR_DEPTH, DEPTH_CAM)
        mm = np.round(depth.depth * 1000).astype(np.uint16)  # and millimetres on this path
        T_ob = T_ODOM_WORLD @ T_world_body
        a = direct.process(i * 1.0, color.rgb, color.depth, T_ob).observations
        b = registered.process(i * 1.0, color.rgb, mm, T_ob).observations
        assert len(a) == len(b), f"frame {i}: {len(a)} vs {len(b)} observations"
        for j in range(len(a)):
            d = np.linalg.norm(b.centroids - a.centroids[j], axis=1)
            m = int(np.argmin(d))
            assert d[m] < 0.05, f"frame {i}: observation {j} moved {d[m]:.3f} m"
            assert b.widths[m] == pytest.approx(a.widths[j], rel=0.1)
            assert b.heights[m] == pytest.approx(a.heights[j], rel=0.1)
            compared += 1
    assert compared >= 10


# ---------------------------------------------------------------------------------------------
# input checks


@pytest.fixture
def frame():
    return render(ring_room(), loop_poses(1)[0] @ T_BC, CAM)


def test_the_widest_camera_accepted_maps_a_frame():
    """Intrinsics like fx = 0.5 for 320 pixels (179.8 deg) used to be accepted and to fail in
    the lift with an IndexError; they are refused now, and the widest camera accepted runs."""
    with pytest.raises(ConfigError, match=r"^PinholeCamera\.fx = 0\.5: "):
        PinholeCamera(320, 240, 0.5, 0.5, 159.5, 119.5)
    wide = PinholeCamera.from_fov(320, 240, 178.0)
    scene = ring_room()
    pose = loop_poses(1)[0]
    shot = render(scene, pose @ T_BC, wide)
    result = RgbdFrontEnd(wide, T_BC, depth_scale=1.0).process(0.0, shot.rgb, shot.depth, pose)
    assert set(result.seconds) == STAGES


def test_seconds_has_the_five_stages(frame):
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0)
    result = front.process(0.0, frame.rgb, frame.depth, np.eye(4))
    assert set(result.seconds) == STAGES
    assert result.n_masks >= len(result.observations) > 0


@pytest.mark.parametrize("rgb", [
    lambda f: f.rgb.astype(np.float32), lambda f: f.rgb[..., 0], lambda f: f.rgb[:-1],
    lambda f: f.rgb[..., :2], lambda f: f.rgb.tolist(),
])
def test_bad_rgb_raises(frame, rgb):
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0)
    with pytest.raises(DataError, match="rgb"):
        front.process(0.0, rgb(frame), frame.depth, np.eye(4))


@pytest.mark.parametrize("depth, match", [
    (lambda f: f.depth.astype(np.int32), "dtype"), (lambda f: f.depth[:, :-1], "shape"),
    (lambda f: f.depth[..., None], "shape"), (lambda f: -f.depth, "negative"),
    (lambda f: f.depth.tolist(), "numpy"),
])
def test_bad_depth_raises(frame, depth, match):
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0)
    with pytest.raises(DataError, match=match):
        front.process(0.0, frame.rgb, depth(frame), np.eye(4))


def test_registered_depth_must_have_the_depth_camera_shape(frame):
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0,
                         registration=DepthRegistration(DEPTH_CAM, T_COLOR_DEPTH))
    with pytest.raises(DataError, match="shape"):
        front.process(0.0, frame.rgb, frame.depth, np.eye(4))  # colour-sized depth


@pytest.mark.parametrize("pose", [np.eye(3), np.full((4, 4), np.nan), np.zeros(16), "pose",
                                  np.diag([1.0, 1.0, np.inf, 1.0])])
def test_bad_pose_raises(frame, pose):
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0)
    with pytest.raises(DataError):
        front.process(0.0, frame.rgb, frame.depth, pose)


def test_time_going_backwards_raises(frame):
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0)
    front.process(1.0, frame.rgb, frame.depth, np.eye(4))
    with pytest.raises(DataError, match="earlier"):
        front.process(0.5, frame.rgb, frame.depth, np.eye(4))


@pytest.mark.parametrize("segmenter", [object(), "fastsam", lambda rgb, depth: None])
def test_segmenter_without_segment_raises_config_error(segmenter):
    with pytest.raises(ConfigError, match="segment"):
        RgbdFrontEnd(CAM, T_BC, segmenter=segmenter)


@pytest.mark.parametrize("T", [np.eye(3), np.full((4, 4), np.nan), None])
def test_bad_body_camera_raises_config_error(T):
    with pytest.raises(ConfigError, match="T_body_camera"):
        RgbdFrontEnd(CAM, T)


def test_segmenter_returning_bad_masks_raises(frame):
    class Bad:
        def segment(self, rgb, depth):
            return np.zeros((1, *CAM.shape), np.uint8)

    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0, segmenter=Bad())
    with pytest.raises(DataError, match="masks"):
        front.process(0.0, frame.rgb, frame.depth, np.eye(4))


def test_a_depth_segmenter_subclass_is_called_through_its_own_segment(frame):
    """The front end reads `DepthSegmenter`'s label image directly, but a subclass that
    overrides `segment` (here to drop every mask) is called through it, its masks checked."""
    from tcaff_gtsam.mapping.segment import DepthSegmenter

    calls = []

    class NoMasks(DepthSegmenter):
        def segment(self, rgb, depth, up=None):
            calls.append(up)
            return super().segment(rgb, depth, up)[:0]

    class NotMasks(DepthSegmenter):
        def segment(self, rgb, depth, up=None):
            return np.zeros((1, *CAM.shape), np.uint8)

    plain = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0)
    assert len(plain.process(0.0, frame.rgb, frame.depth, np.eye(4)).observations) >= 1
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0,
                         segmenter=NoMasks(CAM, 1.0, T_body_camera=T_BC))
    result = front.process(0.0, frame.rgb, frame.depth, np.eye(4))
    assert len(calls) == 1 and result.n_masks == 0 and len(result.observations) == 0
    bad = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0,
                       segmenter=NotMasks(CAM, 1.0, T_body_camera=T_BC))
    with pytest.raises(DataError, match="masks"):
        bad.process(0.0, frame.rgb, frame.depth, np.eye(4))


@pytest.mark.parametrize("seed", range(3))
def test_colour_histograms_from_the_label_image_equal_those_of_the_masks(seed):
    """The depth segmenter's path counts every mask's colours in one pass over its label
    image; the counts are those of the masks themselves, a mask thinner than the sampling
    (every second row and column) included."""
    rng = np.random.default_rng(seed)
    H, W = CAM.shape
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    labels = np.zeros((H, W), np.int32)
    for label in range(1, 9):
        r, c = rng.integers(0, H - 40), rng.integers(0, W - 40)
        labels[r:r + rng.integers(5, 40), c:c + rng.integers(5, 40)] = label
    labels[11, 50:90] = 9  # one odd row: no pixel on the sampling grid
    ids = np.array([label for label in (2, 5, 9, 7) if (labels == label).any()], dtype=np.int64)
    masks = labels[None] == ids[:, None, None].astype(np.int32)
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0)
    per_mask = front._colours(rgb, masks)
    np.testing.assert_allclose(front._colours(rgb, masks, (labels, ids)), per_mask, atol=1e-12)
    np.testing.assert_allclose(per_mask.sum(axis=1), 1.0)
    assert front._colours(rgb, masks[:0], (labels, ids[:0])).shape == (0, per_mask.shape[1])


def test_no_objects_in_view_gives_an_empty_result():
    room = RgbdScene(np.zeros((0, 2)), [], [], walls=room_walls(0, 0, 10, 8))
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0)
    for i, T_world_body in enumerate(loop_poses(20)):
        f = render(room, T_world_body @ T_BC, CAM)
        result = front.process(i * DT, f.rgb, f.depth, T_world_body)
        check_result(result)
        assert len(result.observations) == 0
    assert len(front.object_map().centroids) == 0


def test_coarse_depth_camera_fills_the_colour_image():
    """A depth camera with half the colour camera's resolution: every depth point fills its
    footprint in the colour image, so the registered depth has no grid of holes."""
    coarse = PinholeCamera(160, 120, CAM.fx / 2, CAM.fy / 2, CAM.cx / 2, CAM.cy / 2)
    covered, rel = registration_errors(coarse)
    assert covered > 0.97
    assert np.median(rel) < 0.01
    # no return at all: an empty image of the colour camera's shape, not a (0, 0) array
    empty = register_depth(np.zeros(coarse.shape, np.float32), coarse, CAM, T_COLOR_DEPTH)
    assert empty.shape == CAM.shape and not empty.any()


@pytest.mark.parametrize("kwargs, match", [
    ({"depth_scale": 0}, "depth_scale"),
    ({"depth_scale": "mm"}, "depth_scale"),
    ({"camera": None}, "camera"),
    ({"registration": "x"}, "registration"),
    ({"registration": DepthRegistration(DEPTH_CAM, np.ones((4, 4)))}, "T_color_depth"),
    ({"segmenter": type("Seg", (), {"segment": 3})()}, "segmenter"),
])
def test_bad_front_end_settings_raise_config_error(kwargs, match):
    settings_ = {"camera": CAM, "T_body_camera": T_BC, **kwargs}
    with pytest.raises(ConfigError, match=match):
        RgbdFrontEnd(**settings_)


@pytest.mark.parametrize("masks", [None, [[[True]]], np.zeros((2, 5, 5), bool),
                                   np.zeros((240, 320), bool)])
def test_a_segmenter_returning_bad_masks_is_named(masks):
    seg = type("BrokenSegmenter", (), {"segment": lambda self, rgb, depth: masks})()
    front = RgbdFrontEnd(CAM, T_BC, depth_scale=1.0, segmenter=seg)
    frame = render(ring_room(), loop_poses(5)[0] @ T_BC, CAM)
    with pytest.raises(DataError, match=r"BrokenSegmenter\.segment's masks"):
        front.process(0.0, frame.rgb, frame.depth, np.eye(4))
