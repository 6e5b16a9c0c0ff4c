"""Tests of per-frame gravity in the RGB-D front end: `RgbdFrontEnd.process` tells a segmenter
that takes the keyword `up` the odometry frame's up axis in the camera's optical frame at that
frame, and `DepthSegmenter` uses it to tell level planes (floor, table tops) from walls instead
of the attitude of the mount it was built with. A hand-held camera pitched and rolled is the
case that needs it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rgbd_scenes import CAMERA, SMALL_CAMERA, majority_instance
from tcaff_gtsam.eval.sim.render import RgbdFrame, RgbdScene, render
from tcaff_gtsam.eval.sim.world import room_walls
from tcaff_gtsam.mapping.camera import R_BODY_OPTICAL, T_body_camera
from tcaff_gtsam.mapping.frontend import RgbdFrontEnd
from tcaff_gtsam.mapping.segment import DepthSegmenter, DepthSegmenterParams

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import invert, se3_from_rt, se3_from_xyz_yaw, transform_points

CAM = SMALL_CAMERA  # 320 x 240, 87 deg
#: the mount the front ends are built with: a level camera 1.3 m up (as constructed once)
LEVEL = T_body_camera(1.3, 0.0)
#: odometry = this gravity-aligned (z-preserving) transform of the world frame
T_ODOM_WORLD = se3_from_xyz_yaw(0.5, -1.0, 0.0, 0.4)
TABLE, ON_TABLE = 1, 2  # instance ids in `table_room`
TABLE_HEIGHT = 0.7
#: (x, y, yaw, pitch down deg, roll deg) of a hand-held camera 1.3 m up, per frame
HAND_HELD = [(1.5, 4.0, 0.0, 30.0, 12.0), (1.6, 3.5, 0.3, 28.0, -11.0)]


def rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return {"x": np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])}[axis]


def hand_held(x: float, y: float, yaw: float, pitch_deg: float, roll_deg: float,
              height: float = 1.3) -> np.ndarray:
    """(4, 4) T_world_camera of a camera at (x, y, height) heading `yaw`, pitched down by
    pitch_deg (about the body's y axis) and rolled by roll_deg (about its forward axis)."""
    R = (rot("z", yaw) @ rot("y", math.radians(pitch_deg)) @ rot("x", math.radians(roll_deg))
         @ R_BODY_OPTICAL)
    return se3_from_rt(R, (x, y, height))


def table_room() -> RgbdScene:
    """A 1.2 m table (0.7 m high) with a box standing on it, a box and a cylinder on the floor
    beside it, in a 10 x 8 m room."""
    xy = [[3.2, 4.0], [3.2, 4.0], [3.0, 2.6], [3.6, 5.4]]
    return RgbdScene(xy, [1.2, 0.3, 0.4, 0.5], [TABLE_HEIGHT, 1.0, 0.6, 0.8],
                     [False, False, False, True], [0.2, 0.5, 0.3, 0.0],
                     walls=room_walls(0, 0, 10, 8))


def world_heights(frame: RgbdFrame, T_world_camera: np.ndarray) -> np.ndarray:
    """(H, W) metres: the world z of every pixel's surface point (meaningless without depth)."""
    x_over_z, y_over_z = CAM.rays()
    z = frame.depth
    points = np.stack([x_over_z * z, y_over_z * z, z], axis=-1).reshape(-1, 3)
    return transform_points(T_world_camera, points)[:, 2].reshape(CAM.shape)


def lifted_instances(frame: RgbdFrame, masks: np.ndarray) -> list[int]:
    return [majority_instance(frame.instance, m) for m in masks]


class LevelMountSegmenter:
    """The front end as it was: a `DepthSegmenter` told only its mount (its `segment` takes
    no `up`, so the front end passes none)."""

    def __init__(self, segmenter: DepthSegmenter) -> None:
        self.segmenter = segmenter

    def segment(self, rgb, depth):
        return self.segmenter.segment(rgb, depth)


class Spy:
    """A segmenter that records the `up` it is given and finds nothing."""

    def __init__(self) -> None:
        self.ups: list = []

    def segment(self, rgb, depth, up=None):
        self.ups.append(None if up is None else np.array(up))
        return np.zeros((0, *depth.shape), dtype=bool)


# ---------------------------------------------------------------------------------------------
# what the front end passes


@settings(max_examples=10, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-40.0, 60.0), st.floats(-30.0, 30.0),
       st.floats(-math.pi, math.pi))
def test_front_end_passes_the_odometry_up_axis_in_the_optical_frame(yaw, pitch, roll, tilt):
    """`up` is the odometry frame's z axis in the optical frame, T_odom_camera[2, :3], with
    T_odom_camera = T_odom_body @ T_body_camera (the mount, or the one given with the frame):
    it is where the world's up points in the camera."""
    spy = Spy()
    front = RgbdFrontEnd(CAM, LEVEL, depth_scale=1.0, segmenter=spy)
    rgb = np.zeros((*CAM.shape, 3), np.uint8)
    depth = np.full(CAM.shape, 2.0, np.float32)
    T_world_camera = hand_held(1.0, 2.0, yaw, pitch, roll)
    T_odom_body = T_ODOM_WORLD @ T_world_camera @ invert(LEVEL)
    front.process(0.0, rgb, depth, T_odom_body)
    pan_tilt = T_body_camera(0.8, math.degrees(tilt) / 4)
    front.process(0.1, rgb, depth, T_odom_body, T_body_camera=pan_tilt)
    R_odom_camera = T_ODOM_WORLD[:3, :3] @ T_world_camera[:3, :3]
    # the world's up seen from the camera: R_odom_camera' e_z
    np.testing.assert_allclose(spy.ups[0], R_odom_camera.T @ [0.0, 0.0, 1.0], atol=1e-9)
    expected = (T_odom_body @ pan_tilt)[2, :3]
    np.testing.assert_allclose(spy.ups[1], expected, atol=1e-9)
    assert len(spy.ups) == 2


def test_segmenters_without_the_keyword_get_no_up_and_kwargs_get_it():
    rgb = np.zeros((*CAM.shape, 3), np.uint8)
    depth = np.full(CAM.shape, 2.0, np.float32)
    calls = []

    class Plain:
        def segment(self, rgb, depth):
            calls.append("plain")
            return np.zeros((0, *depth.shape), dtype=bool)

    class Loose:
        def segment(self, rgb, depth, **kwargs):
            calls.append(kwargs)
            return np.zeros((0, *depth.shape), dtype=bool)

    T = hand_held(0.0, 0.0, 0.0, 30.0, 12.0) @ invert(LEVEL)
    RgbdFrontEnd(CAM, LEVEL, depth_scale=1.0, segmenter=Plain()).process(0.0, rgb, depth, T)
    RgbdFrontEnd(CAM, LEVEL, depth_scale=1.0, segmenter=Loose()).process(0.0, rgb, depth, T)
    assert calls[0] == "plain"
    assert set(calls[1]) == {"up"}
    np.testing.assert_allclose(calls[1]["up"], (T @ LEVEL)[2, :3], atol=1e-12)


# ---------------------------------------------------------------------------------------------
# the depth segmenter


def test_up_given_per_frame_is_the_attitude_given_at_construction():
    """Segmenting with `up` gives the labels of a segmenter built with that attitude, and
    differs from the level mount's (the table top is level only in the right gravity)."""
    scene = table_room()
    T_wc = hand_held(*HAND_HELD[0])
    frame = render(scene, T_wc, CAM)
    level = DepthSegmenter(CAM, 1.0, T_body_camera=LEVEL)
    tilted = DepthSegmenter(CAM, 1.0, T_body_camera=T_wc)
    np.testing.assert_allclose(tilted.up, T_wc[2, :3], atol=1e-12)
    labels_up, n_up = level.label(frame.rgb, frame.depth, up=T_wc[2, :3])
    labels_built, n_built = tilted.label(frame.rgb, frame.depth)
    assert n_up == n_built
    np.testing.assert_array_equal(labels_up, labels_built)
    # a scaled up is the same direction
    labels_scaled, _ = level.label(frame.rgb, frame.depth, up=3.0 * T_wc[2, :3])
    np.testing.assert_array_equal(labels_scaled, labels_up)
    labels_level, _ = level.label(frame.rgb, frame.depth)
    assert not np.array_equal(labels_level, labels_up)
    masks = level.segment(frame.rgb, frame.depth, up=T_wc[2, :3])
    assert masks.shape[0] == n_up
    for i in range(n_up):
        np.testing.assert_array_equal(masks[i], labels_up == i + 1)


@pytest.mark.parametrize("up", [np.zeros(3), [0.0, math.nan, 1.0], [0.0, 1.0], "up",
                                np.ones((3, 1)), [math.inf, 0.0, 0.0]], ids=repr)
def test_bad_up_is_a_data_error_naming_it(up):
    segmenter = DepthSegmenter(CAM, 1.0, T_body_camera=LEVEL)
    depth = np.full(CAM.shape, 2.0, np.float32)
    with pytest.raises(DataError, match="up"):
        segmenter.label(None, depth, up=up)
    with pytest.raises(DataError, match="up"):
        segmenter.segment(None, depth, up=up)


# ---------------------------------------------------------------------------------------------
# a hand-held camera, pitched and rolled


def test_hand_held_camera_removes_level_planes_with_its_own_gravity():
    """A camera 1.3 m up, pitched 30 deg down and rolled 12 deg (then 28 deg and -11 deg), in
    a front end built with a level mount and given the true pose per frame: no lifted mask is
    floor or other room structure, the table top is removed (so the box standing on it is a
    mask of its own) and the table and the box are found. The same frames through the front
    end as it was (the mount's gravity, 30 to 32 deg off) keep the table top and miss the box."""
    scene = table_room()
    front = RgbdFrontEnd(CAM, LEVEL, depth_scale=1.0)
    old = RgbdFrontEnd(CAM, LEVEL, depth_scale=1.0,
                       segmenter=LevelMountSegmenter(DepthSegmenter(CAM, 1.0,
                                                                    T_body_camera=LEVEL)))
    for i, pose in enumerate(HAND_HELD):
        T_wc = hand_held(*pose)
        off = math.degrees(math.acos(T_wc[2, :3] @ LEVEL[2, :3]))
        assert off > 25.0, "the camera is meant to be far from level"
        frame = render(scene, T_wc, CAM)
        for k in (TABLE, ON_TABLE):  # wholly in view
            gt = frame.instance == k
            assert gt.any() and not (gt[:4].any() or gt[-4:].any() or gt[:, :4].any()
                                     or gt[:, -4:].any())
        z = world_heights(frame, T_wc)
        floor = (frame.depth > 0) & (z < 0.02)
        table_top = (frame.instance == TABLE) & (np.abs(z - TABLE_HEIGHT) < 0.01)
        assert np.count_nonzero(table_top) > 500
        T_odom_body = T_ODOM_WORLD @ T_wc @ invert(LEVEL)

        result = front.process(0.1 * i, frame.rgb, frame.depth, T_odom_body)
        found = lifted_instances(frame, result.masks)
        assert 0 not in found, f"frame {i}: lifted room structure ({found})"
        for mask in result.masks:
            assert np.mean(floor[mask]) < 0.05, f"frame {i}: a lifted mask holds floor"
            assert np.mean(table_top[mask]) < 0.05, f"frame {i}: a mask holds the table top"
        assert TABLE in found and ON_TABLE in found, f"frame {i}: lifted {found}"
        box = result.masks[found.index(ON_TABLE)]
        assert np.count_nonzero(box & (frame.instance == ON_TABLE)) > 0.8 * np.count_nonzero(box)

        # the mount's gravity: the table top is not level, stays, and joins the box to it
        was = old.process(0.1 * i, frame.rgb, frame.depth, T_odom_body)
        found_then = lifted_instances(frame, was.masks)
        lifts_floor = 0 in found_then or any(np.mean(floor[m]) > 0.2 for m in was.masks)
        assert ON_TABLE not in found_then or lifts_floor, (
            f"frame {i}: the level mount's gravity found the box on the table too "
            f"({found_then}): per-frame gravity would not be needed here")
        # the segmenter itself: the mount's gravity (up=None) leaves the table top in a mask,
        # this frame's removes it
        labels, _ = front.segmenter.label(frame.rgb, frame.depth)
        assert np.count_nonzero((labels > 0) & table_top) > 0.5 * np.count_nonzero(table_top)
        labels, _ = front.segmenter.label(frame.rgb, frame.depth, up=T_wc[2, :3])
        assert np.count_nonzero((labels > 0) & table_top) < 0.05 * np.count_nonzero(table_top)


def test_hand_held_camera_lifts_each_object_once():
    """With per-frame gravity the table top (0.7 m) is a level plane, and its band runs through
    the 0.8 m cylinder beside the table as a slice a few pixels tall. The slice stays with the
    cylinder: it is lifted once, from a mask holding nearly all of it, at nearly its height."""
    scene = table_room()
    front = RgbdFrontEnd(CAM, LEVEL, depth_scale=1.0)
    T_wc = hand_held(*HAND_HELD[0])
    frame = render(scene, T_wc, CAM)
    cylinder = 4
    gt = frame.instance == cylinder
    assert gt.any() and not (gt[:4].any() or gt[-4:].any() or gt[:, :4].any()
                             or gt[:, -4:].any())
    result = front.process(0.0, frame.rgb, frame.depth, T_ODOM_WORLD @ T_wc @ invert(LEVEL))
    found = lifted_instances(frame, result.masks)
    assert found.count(cylinder) == 1, f"lifted {found}"
    i = found.index(cylinder)
    assert np.count_nonzero(result.masks[i] & gt) > 0.9 * np.count_nonzero(gt)
    assert result.observations.heights[i] > 0.7
    # the rule is what does it: without it (level_slice=0) the band cuts the cylinder in two
    sliced = DepthSegmenter(CAM, 1.0, DepthSegmenterParams(level_slice=0), T_body_camera=LEVEL)
    labels, _ = sliced.label(frame.rgb, frame.depth, up=T_wc[2, :3])
    parts = np.bincount(labels[gt])[1:]
    assert np.count_nonzero(parts > 0.1 * np.count_nonzero(gt)) == 2


@pytest.mark.parametrize("roll", [-30.0, 0.0, 30.0, 45.0, 60.0])
@pytest.mark.parametrize("camera", [CAM, CAMERA], ids=["320 px", "640 px"])
def test_a_rolled_camera_keeps_the_slice_with_the_object(roll, camera):
    """The slice is looked for along the image's up direction: along columns up to a roll of
    45 deg, along rows past it, and an upright side scanned obliquely (rolled 30-60 deg) is
    still steep. At 640 x 480 the image is segmented on a grid of every second pixel, on
    which `level_slice` is counted in grid pixels. The cylinder is one segment at every roll."""
    scene = table_room()
    T_wc = hand_held(*HAND_HELD[0][:4], roll)
    frame = render(scene, T_wc, camera)
    gt = frame.instance == 4
    assert np.count_nonzero(gt) > 500
    segmenter = DepthSegmenter(camera, 1.0, T_body_camera=LEVEL)
    labels, _ = segmenter.label(frame.rgb, frame.depth, up=T_wc[2, :3])
    parts = np.bincount(labels[gt])[1:]
    assert parts.max() > 0.9 * np.count_nonzero(gt), f"roll {roll}: parts {parts[parts > 0]}"


@pytest.mark.parametrize("pose", [(1.3, 12.0, 8.0, 1.0), (1.1, 15.0, -10.0, 1.05)])
def test_a_table_top_seen_edge_on_is_not_kept_as_a_slice(pose):
    """A box stands on a 2 m table 0.1 m behind its front edge, seen from just above the
    table (0.3-0.35 m): between the box and the table's front, the table top is a strip a few
    pixels tall, continuous in depth (0.1 m is less than a depth jump there). It is the plane
    itself, not a slice through an object (its ends are at one height, the table's depth
    apart along the line of sight), so it stays removed and the box stays apart from the
    table; keeping every short run without a depth jump would join them."""
    distance, pitch, roll, height = pose
    edge = 2.2  # x of the table's front edge
    scene = RgbdScene([[3.2, 4.0], [edge + 0.1 + 0.15, 4.0]], [2.0, 0.3], [TABLE_HEIGHT, 1.0],
                      walls=room_walls(0, 0, 10, 8))
    T_wc = hand_held(edge - distance, 4.05, 0.0, pitch, roll, height=height)
    frame = render(scene, T_wc, CAM)
    table_top = (frame.instance == 1) & (np.abs(world_heights(frame, T_wc) - TABLE_HEIGHT)
                                         < 0.01)
    segmenter = DepthSegmenter(CAM, 1.0, T_body_camera=LEVEL)
    labels, _ = segmenter.label(frame.rgb, frame.depth, up=T_wc[2, :3])
    assert np.count_nonzero((labels > 0) & table_top) < 0.05 * np.count_nonzero(table_top)
    box = frame.instance == 2
    label = np.bincount(labels[box]).argmax()
    assert label > 0 and np.count_nonzero(labels[box] == label) > 0.8 * np.count_nonzero(box)
    mask = labels == label
    assert np.count_nonzero(mask & (frame.instance == 1)) < 0.02 * np.count_nonzero(mask)


def test_a_noisy_floor_stays_removed():
    """Depth noise (0.0025 z^2 m) leaves specks of the floor outside its band; the runs of the
    band between them are level, not slices, and stay removed: no lifted mask is floor, and
    the cylinder is still lifted once."""
    scene = table_room()
    for seed, pose in enumerate(HAND_HELD):
        T_wc = hand_held(*pose)
        frame = render(scene, T_wc, CAM, depth_noise=0.0025, rng=np.random.default_rng(seed))
        floor = (frame.depth > 0) & (world_heights(frame, T_wc) < 0.03)
        front = RgbdFrontEnd(CAM, LEVEL, depth_scale=1.0)
        result = front.process(0.0, frame.rgb, frame.depth,
                               T_ODOM_WORLD @ T_wc @ invert(LEVEL))
        found = lifted_instances(frame, result.masks)
        assert 0 not in found and found.count(4) == 1, f"frame {seed}: lifted {found}"
        for mask in result.masks:
            assert np.mean(floor[mask]) < 0.05, f"frame {seed}: a lifted mask holds floor"
