"""Tests of the front end's structure rules on rendered rooms as real sensors see them: a floor,
a ceiling, walls with cabinets, chairs and desk-side objects against them, and a band without
depth along the image edges. What must be found is found (every clearly visible object, once
per frame); what must not be is not (no floor, ceiling or wall patch, no object cut by the band).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from rgbd_scenes import CAMERA, bbox_size, camera_pose, majority_instance, solo
from tcaff_gtsam.eval.sim.render import RgbdFrame, RgbdScene, render
from tcaff_gtsam.eval.sim.world import room_walls
from tcaff_gtsam.mapping.camera import T_body_camera
from tcaff_gtsam.mapping.frontend import FrameResult, RgbdFrontEnd
from tcaff_gtsam.mapping.segment import (
    DepthSegmenter,
    DepthSegmenterParams,
    MaskFilter,
    depth_border,
)

from tcaff_gtsam.geometry import transform_points

WALL_HEIGHT = 2.5  # metres, also the ceiling's height
#: pixels without depth along the (top, bottom, left, right) edges, wider on the left as in a
#: depth camera registered to a colour camera beside it
BAND = (6, 10, 24, 8)
MIN_SIDE = 30  # pixels: objects smaller than this in either direction are not checked

#: (x, y, width, height, cylinder) of objects in a 10 x 8 m room: flush against the walls
#: (cabinets, desk-side boxes, a bin), a little in front of them (chairs) and free standing.
FURNITURE = [
    (0.3, 2.0, 0.6, 1.2, False),  # cabinet flush against the x = 0 wall
    (0.3, 3.2, 0.6, 1.1, False),  # a lower one beside it, its front in the same plane
    (0.2, 5.0, 0.4, 0.5, False),  # desk-side box against the wall
    (0.55, 6.3, 0.5, 0.9, False),  # chair 0.3 m from the wall
    (9.82, 2.5, 0.36, 0.45, True),  # bin against the x = 10 wall
    (9.7, 4.5, 0.6, 1.3, False),  # cabinet flush against the x = 10 wall
    (9.4, 6.0, 0.5, 0.95, False),  # chair 0.35 m from the wall
    (5.0, 7.7, 0.6, 0.75, False),  # cabinet against the y = 8 wall
    (3.5, 0.25, 0.5, 1.0, False),  # box against the y = 0 wall
    (6.5, 0.45, 0.45, 0.9, False),  # chair near the y = 0 wall
    (5.0, 4.0, 0.5, 1.0, True),  # free standing
]
#: robot (x, y, yaw) facing each wall and two corners
POSES = [(3.0, 4.0, math.pi), (7.0, 4.0, 0.0), (5.0, 3.0, -math.pi / 2),
         (5.0, 4.5, math.pi / 2), (2.5, 2.5, -2.4), (7.5, 5.5, 0.8)]
#: camera mounts: a robot's (0.6 m, 5 deg down), a hand-held one (1.3 m, 15 deg down) and one
#: looking up at the ceiling (1.0 m, 10 deg up)
MOUNTS = {"robot": T_body_camera(0.6, 5.0), "hand-held": T_body_camera(1.3, 15.0),
          "looking-up": T_body_camera(1.0, -10.0)}


def furnished_room(furniture=FURNITURE) -> RgbdScene:
    f = np.array([row[:4] for row in furniture], dtype=float)
    return RgbdScene(f[:, :2], f[:, 2], f[:, 3], [row[4] for row in furniture],
                     walls=room_walls(0, 0, 10, 8), wall_height=WALL_HEIGHT, ceiling=True)


def near_band(frame: RgbdFrame, reach: int) -> np.ndarray:
    """(H, W) bool: pixels within `reach` pixels of the image edge or of the band without
    depth along it (as the mask filter finds that band)."""
    band = depth_border(frame.depth > 0, MaskFilter().invalid_margin)
    return cv2.dilate(band.view(np.uint8), np.ones((2 * reach + 1,) * 2, np.uint8)).view(bool)


def clearly_visible(scene: RgbdScene, frame: RgbdFrame, T_world_camera: np.ndarray, k: int,
                    mask_filter: MaskFilter) -> bool:
    """Object k is wholly in view, clear of the band without depth, of a size the filter
    keeps, at least MIN_SIDE pixels each way, and unoccluded (as many pixels as when alone in
    the room)."""
    gt = frame.instance == k + 1
    area = np.count_nonzero(gt)
    if not mask_filter.min_area <= area <= mask_filter.max_area_share * gt.size:
        return False
    if min(bbox_size(gt)) < MIN_SIDE or (gt & near_band(frame, mask_filter.border + 1)).any():
        return False
    alone = render(solo(scene, k), T_world_camera, CAMERA).instance == 1
    return np.count_nonzero(alone) == area


def structure_kind(z: float) -> str:
    """What room structure a lifted centroid at height z (world frame) would be on."""
    if z < 0.15:
        return "floor"
    return "ceiling" if z > WALL_HEIGHT - 0.15 else "wall"


def check_frame(scene: RgbdScene, frame: RgbdFrame, T_world_camera: np.ndarray,
                result: FrameResult, mask_filter: MaskFilter,
                visible: list[int] | None = None) -> tuple[int, list[str]]:
    """(number of clearly visible objects, failures) of one processed frame; `visible`: the
    clearly visible objects, when known already."""
    failures = []
    labels = []
    obs = result.observations
    for mask, c, w, h in zip(result.masks, obs.centroids, obs.widths, obs.heights,
                             strict=True):
        lab = majority_instance(frame.instance, mask)
        share = np.count_nonzero(frame.instance[mask] == lab) / np.count_nonzero(mask)
        labels.append(lab)
        what = f"{w:.2f} x {h:.2f} m at {np.round(c, 2)}"
        if lab == 0:
            failures.append(f"lifted {structure_kind(c[2])}: {what}")
            continue
        k = lab - 1
        if share < 0.5:
            failures.append(f"object {k} lifted from a mask only {share:.0%} of it: {what}")
        if w > 1.25 * scene.widths[k] + 0.05 or h > 1.25 * scene.heights[k] + 0.05:
            failures.append(f"object {k} ({scene.widths[k]:.2f} x {scene.heights[k]:.2f} m) "
                            f"lifted with structure attached: {what}")
        if (frame.instance == lab)[near_band(frame, 1)].any():
            failures.append(f"object {k} is cut by the image edge or the band without depth "
                            f"but was lifted: {what}")
    if visible is None:
        visible = [k for k in range(len(scene))
                   if clearly_visible(scene, frame, T_world_camera, k, mask_filter)]
    for k in visible:
        n = labels.count(k + 1)
        if n != 1:
            failures.append(f"object {k} ({scene.widths[k]:.2f} x {scene.heights[k]:.2f} m) "
                            f"clearly visible but lifted {n} times")
    return len(visible), failures


@pytest.fixture(scope="module")
def furnished_views():
    """(mount, mask filter) -> for each of POSES: T_world_camera, the frame, the objects
    clearly visible in it and the share of its returns on the ceiling. Made once for both
    grids of the segmenter, which see the same frames."""
    scene, made = furnished_room(), {}

    def views(mount: str, mask_filter: MaskFilter) -> list:
        if (mount, mask_filter) not in made:
            made[mount, mask_filter] = []
            for x, y, yaw in POSES:
                T_wc = camera_pose(x, y, yaw, MOUNTS[mount])
                frame = render(scene, T_wc, CAMERA, invalid_border=BAND)
                visible = [k for k in range(len(scene))
                           if clearly_visible(scene, frame, T_wc, k, mask_filter)]
                v, u = np.nonzero(frame.depth > 0)
                rays = np.linalg.inv(CAMERA.K) @ np.vstack([u, v, np.ones_like(u)])
                z = T_wc[2, :3] @ (rays * frame.depth[v, u]) + T_wc[2, 3]  # world heights
                made[mount, mask_filter].append(
                    (T_wc, frame, visible, np.mean(z > WALL_HEIGHT - 0.01)))
        return made[mount, mask_filter]

    return views


@pytest.mark.parametrize("grid", ["coarse", "full"])
@pytest.mark.parametrize("mount", list(MOUNTS))
def test_furnished_room_finds_the_objects_and_no_structure(mount, grid, furnished_views):
    """With the segmenter's default grid (every second row and column of these 640 x 480
    frames) and at full resolution."""
    T_bc = MOUNTS[mount]
    scene = furnished_room()
    params = DepthSegmenterParams() if grid == "coarse" else DepthSegmenterParams(work_width=0)
    segmenter = DepthSegmenter(CAMERA, 1.0, params, T_body_camera=T_bc)
    assert segmenter.step == (2 if grid == "coarse" else 1)
    front = RgbdFrontEnd(CAMERA, T_bc, depth_scale=1.0, segmenter=segmenter)
    checked, failures, ceiling_share = 0, [], 0.0
    views = furnished_views(mount, front.mask_filter)
    for i, ((x, y, yaw), (T_wc, frame, visible, ceiling)) in enumerate(
            zip(POSES, views, strict=True)):
        result = front.process(float(i), frame.rgb, frame.depth, camera_pose(x, y, yaw,
                                                                             np.eye(4)))
        n, f = check_frame(scene, frame, T_wc, result, front.mask_filter, visible)
        checked += n
        failures += [f"pose {i} ({x}, {y}, {yaw:.2f}): {m}" for m in f]
        # the scenes hold what they are meant to: the ceiling in view, no depth in the band
        ceiling_share = max(ceiling_share, ceiling)
        top, bottom, left, right = BAND
        assert not frame.depth[:top].any() and not frame.depth[:, :left].any()
        assert not frame.depth[-bottom:].any() and not frame.depth[:, -right:].any()
    assert checked >= 6, "the poses should show several objects clearly"
    assert ceiling_share > 0.01, "some frame should show the ceiling"
    assert not failures, "\n".join(failures)


def processed(scene: RgbdScene, x: float, y: float, yaw: float, mount: str):
    """(frame, T_world_camera, front end, result) of one view of `scene` from a robot at
    (x, y, yaw) with the camera `mount`."""
    T_bc = MOUNTS[mount]
    T_wc = camera_pose(x, y, yaw, T_bc)
    frame = render(scene, T_wc, CAMERA, invalid_border=BAND)
    front = RgbdFrontEnd(CAMERA, T_bc, depth_scale=1.0)
    return frame, T_wc, front, front.process(0.0, frame.rgb, frame.depth,
                                             camera_pose(x, y, yaw, np.eye(4)))


def test_tall_cabinet_against_a_wall_is_found():
    """A 1.9 m cabinet flush against a wall, face on from 2.7 m with the robot's camera: its
    front spans more than `plane_min_extent`, but the wall shows beside it and above it."""
    scene = furnished_room([(9.7, 4.5, 0.6, 1.9, False), (5.0, 4.0, 0.5, 1.0, True)])
    frame, T_wc, front, result = processed(scene, 7.0, 4.0, 0.0, "robot")
    assert clearly_visible(scene, frame, T_wc, 0, front.mask_filter)
    n, failures = check_frame(scene, frame, T_wc, result, front.mask_filter)
    assert n >= 1 and not failures, "\n".join(failures)


@pytest.mark.parametrize("mount", list(MOUNTS))
@pytest.mark.parametrize("where", ["mid-wall", "corner"])
def test_wide_cabinet_against_a_wall_is_found(mount, where):
    """A 1.8 m wide, 1 m tall sideboard against the x = 10 wall (its front at x = 9.5), face
    on from 2.5 m, or pushed into the corner with the y = 8 wall and seen from the side: its
    front is a plane of its own, wider than `plane_min_extent` and as wide as the lifter's
    `wall_extent`, but the wall shows beside it (on one side only in the corner) and above."""
    y, pose = {"mid-wall": (4.0, (7.0, 4.0, 0.0)), "corner": (7.1, (7.0, 6.5, 0.2))}[where]
    scene = RgbdScene([[10.4, y], [5.0, 1.5]], [1.8, 0.5], [1.0, 1.0], [False, True],
                      walls=room_walls(0, 0, 10, 8), wall_height=WALL_HEIGHT, ceiling=True)
    frame, T_wc, front, result = processed(scene, *pose, mount)
    assert clearly_visible(scene, frame, T_wc, 0, front.mask_filter)
    n, failures = check_frame(scene, frame, T_wc, result, front.mask_filter)
    assert n == 1 and not failures, "\n".join(failures)
    assert result.observations.widths[0] >= 1.5


@pytest.mark.parametrize("distance", [4.0, 4.5])
def test_partition_from_floor_to_ceiling_is_wall(distance):
    """A 2 m wide partition standing free in the room, from the floor to the ceiling, seen
    face on with the ceiling in view: it stands in front of the wall behind it on both sides as
    a cabinet does, but it meets the ceiling, so it is wall: no segment is on it."""
    walls = np.concatenate([room_walls(0, 0, 10, 8), [[(8.0, 3.0), (8.0, 5.0)]]])
    scene = RgbdScene([[5.0, 7.0]], [0.4], [0.5], [True], walls=walls,
                      wall_height=WALL_HEIGHT, ceiling=True)
    frame, T_wc, front, result = processed(scene, 8.0 - distance, 4.0, 0.0, "robot")
    v, u = np.nonzero(frame.depth > 0)
    rays = np.linalg.solve(CAMERA.K, np.vstack([u, v, np.ones_like(u)]))
    xyz = transform_points(T_wc, (rays * frame.depth[v, u]).T)
    partition = np.zeros(CAMERA.shape, dtype=bool)
    # the partition is 0.1 m thick: its face is at x = 7.95
    partition[v, u] = (np.abs(xyz[:, 0] - 7.95) < 0.02) & (np.abs(xyz[:, 1] - 4.0) < 1.0)
    ceiling = np.zeros(CAMERA.shape, dtype=bool)
    ceiling[v, u] = xyz[:, 2] > WALL_HEIGHT - 0.01
    assert np.count_nonzero(partition) > 0.08 * partition.size and ceiling.any()
    masks = front.segmenter.segment(frame.rgb, frame.depth)
    on_partition = (masks & partition).sum(axis=(1, 2))
    assert np.all(on_partition < 0.1 * np.count_nonzero(partition)), on_partition
    assert len(result.observations) == 0


@pytest.mark.parametrize("mount", list(MOUNTS))
def test_cabinet_wider_than_the_view_is_not_lifted(mount):
    """A 6 m long, 1 m tall counter against the wall, 1.5 m ahead, fills the view from side
    to side: like any object cut by the edge of the view, it is not lifted (its centroid and
    size would be wrong), and neither is the wall above it."""
    scene = RgbdScene([[12.5, 4.0]], [6.0], [1.0], [False], walls=room_walls(0, 0, 10, 8),
                      wall_height=WALL_HEIGHT, ceiling=True)
    frame, _, _, result = processed(scene, 8.0, 4.0, 0.0, mount)
    counter = frame.instance == 1
    assert counter[:, BAND[2]].any() and counter[:, -BAND[3] - 1].any()
    assert len(result.observations) == 0
