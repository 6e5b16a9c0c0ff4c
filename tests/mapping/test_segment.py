"""Tests for tcaff_gtsam.mapping.segment: the depth segmenter on rendered rooms (the issue's
acceptance: masks match the ground-truth instances), determinism, the mask filters and input
checks."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from rgbd_scenes import (
    CAMERA,
    ROOM,
    bbox_size,
    camera_pose,
    free_pose,
    iou,
    pose_facing,
    random_room,
    solo,
    touches_border,
)
from tcaff_gtsam.eval.sim.render import RgbdScene, render
from tcaff_gtsam.eval.sim.world import room_walls
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera
from tcaff_gtsam.mapping.masks import MAX_BORDER
from tcaff_gtsam.mapping.segment import (
    INVALID_MARGIN,
    MAX_PLANES,
    MAX_RANSAC_ITERATIONS,
    DepthSegmenter,
    DepthSegmenterParams,
    MaskFilter,
    Segmenter,
    _median_network,
    _sampled_median,
    check_rgb,
    depth_border,
    filter_labels,
    filter_masks,
    stands_in_front,
)

from tcaff_gtsam.errors import ConfigError, DataError

MIN_IOU = 0.8
MIN_SIDE = 30  # pixels: objects whose bounding box is at least this big in both directions


def unoccluded_objects(scene: RgbdScene, T: np.ndarray, frame) -> list[int]:
    """Objects fully visible in `frame` (as many pixels as when alone in the room), at least
    MIN_SIDE x MIN_SIDE pixels and not touching the image border or the band without depth
    along it (the open space above the walls when they end near the top of the image, which
    the segmenter cannot tell from a sensor's invalid border)."""
    band = cv2.dilate(depth_border(frame.depth > 0, INVALID_MARGIN).view(np.uint8),
                      np.ones((3, 3), np.uint8)).view(bool)
    out = []
    for k in range(len(scene)):
        gt = frame.instance == k + 1
        if not gt.any() or touches_border(gt) or (gt & band).any():
            continue
        if min(bbox_size(gt)) < MIN_SIDE:
            continue
        alone = render(solo(scene, k), T, CAMERA).instance == 1
        if np.count_nonzero(gt) == np.count_nonzero(alone):
            out.append(k)
    return out


def check_frame(scene: RgbdScene, T: np.ndarray, segmenter: DepthSegmenter,
                mask_filter: MaskFilter) -> tuple[int, list[str]]:
    """(number of objects checked, failure descriptions) of one rendered frame."""
    frame = render(scene, T, CAMERA)
    masks = segmenter.segment(frame.rgb, frame.depth)
    assert masks.dtype == np.bool_ and masks.shape[1:] == CAMERA.shape
    kept = filter_masks(masks, frame.depth, mask_filter)
    failures = []
    objects = unoccluded_objects(scene, T, frame)
    for k in objects:
        gt = frame.instance == k + 1
        scores = [iou(m, gt) for m in masks]
        best = int(np.argmax(scores)) if scores else -1
        kind = "cylinder" if scene.cylinders[k] else "box"
        what = (f"object {k} ({kind} {scene.widths[k]:.2f} x {scene.heights[k]:.2f} m at "
                f"{np.hypot(*(scene.xy[k] - T[:2, 3])):.2f} m, {np.count_nonzero(gt)} px)")
        if best < 0 or scores[best] < MIN_IOU:
            failures.append(f"{what}: best IoU {max(scores, default=0.0):.3f}")
        elif best not in kept and np.count_nonzero(masks[best]) <= (
                mask_filter.max_area_share * gt.size):
            failures.append(f"{what}: its mask (IoU {scores[best]:.3f}) is dropped by the filter")
    return len(objects), failures


# ---------------------------------------------------------------------------------------------
# acceptance on rendered rooms


@pytest.mark.parametrize("seed", range(8))
def test_masks_match_unoccluded_objects(seed):
    """Random rooms of six boxes and cylinders; one random pose and two facing an object."""
    rng = np.random.default_rng(seed)
    scene = random_room(rng, 6)
    segmenter = DepthSegmenter(CAMERA, 1.0)
    checked, failures = 0, []
    for p in range(3):
        if p == 0:
            x, y, yaw = free_pose(rng, scene)
        else:
            x, y, yaw = pose_facing(rng, scene, int(rng.integers(len(scene))), (1.0, 5.0))
        n, f = check_frame(scene, camera_pose(x, y, yaw), segmenter, MaskFilter())
        checked += n
        failures += [f"pose {p} ({x:.2f}, {y:.2f}, {yaw:.3f}): {m}" for m in f]
    assert checked >= 2, "the scene should show some unoccluded objects"
    assert not failures, "\n".join(failures)


def test_near_cylinder_among_objects_is_segmented():
    """A fixed scene (found by the random test): a 0.65 m cylinder 1.48 m ahead, fully in view,
    with six other objects in the room. The cylinder's front is nearly flat over a large area
    and must not be removed as a 'dominant plane'."""
    xy = [[5.758, 5.485], [1.644, 3.681], [8.660, 5.586], [3.369, 5.528], [2.772, 1.678],
          [6.647, 1.711], [6.254, 3.490]]
    widths = [0.648, 0.644, 0.302, 0.420, 0.491, 0.620, 0.528]
    heights = [1.116, 0.885, 0.716, 1.388, 0.527, 0.407, 1.055]
    cylinders = [True, False, False, False, False, True, True]
    yaws = [1.438, 0.102, 1.108, 1.549, 1.512, 0.282, 0.761]
    scene = RgbdScene(xy, widths, heights, cylinders, yaws, walls=room_walls(*ROOM))
    T = camera_pose(7.2359, 5.3514, -2.8937)
    checked, failures = check_frame(scene, T, DepthSegmenter(CAMERA, 1.0), MaskFilter())
    assert checked >= 1
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize("distance", [1.5, 2.5, 4.0])
@pytest.mark.parametrize("cylinder", [False, True])
def test_single_object_straight_ahead(distance, cylinder):
    scene = RgbdScene([[5.0, 4.0]], [0.5], [1.0], [cylinder], [0.4], walls=room_walls(*ROOM))
    T = camera_pose(5.0 - distance, 4.0, 0.0)
    checked, failures = check_frame(scene, T, DepthSegmenter(CAMERA, 1.0), MaskFilter())
    assert checked == 1
    assert not failures, "\n".join(failures)


def test_same_frame_gives_identical_masks():
    rng = np.random.default_rng(5)
    scene = random_room(rng, 6)
    T = camera_pose(*pose_facing(rng, scene, 0))
    frame = render(scene, T, CAMERA, depth_noise=0.0025, rng=rng)
    a = DepthSegmenter(CAMERA, 1.0).segment(frame.rgb, frame.depth)
    seg = DepthSegmenter(CAMERA, 1.0)
    b = seg.segment(frame.rgb, frame.depth)
    c = seg.segment(None, frame.depth.copy())
    assert a.shape[0] > 0
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)


def test_masks_are_disjoint_largest_first_and_match_the_label_image():
    rng = np.random.default_rng(11)
    scene = random_room(rng, 6)
    frame = render(scene, camera_pose(*pose_facing(rng, scene, 0)), CAMERA)
    seg = DepthSegmenter(CAMERA, 1.0)
    masks = seg.segment(frame.rgb, frame.depth)
    labels, count = seg.label(frame.rgb, frame.depth)
    assert labels.dtype == np.int32 and count == masks.shape[0] > 0
    assert masks.sum(axis=0).max() == 1
    areas = masks.reshape(count, -1).sum(axis=1)
    assert np.all(np.diff(areas) <= 0)
    for i in range(count):
        np.testing.assert_array_equal(masks[i], labels == i + 1)
    # every mask is large enough and none covers pixels without depth
    assert areas.min() >= seg.params.min_area
    assert not (masks & (frame.depth == 0)).any()


def test_millimetre_depth_gives_the_same_masks():
    rng = np.random.default_rng(2)
    scene = random_room(rng, 6)
    frame = render(scene, camera_pose(*pose_facing(rng, scene, 0)), CAMERA)
    metres = DepthSegmenter(CAMERA, 1.0).segment(frame.rgb, frame.depth)
    mm = np.round(frame.depth * 1000).astype(np.uint16)
    millis = DepthSegmenter(CAMERA, 1000.0).segment(frame.rgb, mm)
    assert metres.shape[0] == millis.shape[0] > 0
    for a, b in zip(metres, millis, strict=True):
        assert iou(a, b) > 0.98


@pytest.mark.parametrize("yaw", np.linspace(0, 2 * np.pi, 6, endpoint=False))
@pytest.mark.parametrize("where", [(5.0, 4.0), (1.5, 1.5), (8.0, 6.5)])
def test_empty_room_gives_no_masks_after_filtering(yaw, where):
    scene = RgbdScene(np.zeros((0, 2)), [], [], walls=room_walls(*ROOM))
    frame = render(scene, camera_pose(*where, yaw), CAMERA)
    masks = DepthSegmenter(CAMERA, 1.0).segment(frame.rgb, frame.depth)
    kept = filter_masks(masks, frame.depth, MaskFilter())
    assert kept.size == 0, f"{kept.size} masks of {masks.shape[0]} survive in an empty room"


def test_empty_and_invalid_depth_gives_no_masks():
    seg = DepthSegmenter(CAMERA, 1.0)
    masks = seg.segment(None, np.zeros(CAMERA.shape, np.float32))
    assert masks.shape == (0, *CAMERA.shape) and masks.dtype == np.bool_
    # depths outside [depth_min, depth_max] count as no return
    far = np.full(CAMERA.shape, 9.0, np.float32)
    far[200:260, 300:360] = 0.1
    assert seg.segment(None, far).shape[0] == 0


def test_segmenter_is_a_segmenter():
    assert isinstance(DepthSegmenter(CAMERA), Segmenter)


# ---------------------------------------------------------------------------------------------
# filter_masks

H, W = 120, 160


def rect(r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    m = np.zeros((H, W), dtype=bool)
    m[r0:r1, c0:c1] = True
    return m


def test_filter_drops_each_kind_of_bad_mask():
    depth = np.full((H, W), 2.0, dtype=np.float32)
    depth[80:110, 100:130] = 0.0  # a patch without depth
    masks = np.stack([
        rect(40, 70, 40, 70),    # 0: good, 900 px
        rect(0, 30, 40, 70),     # 1: touches the top border
        rect(40, 70, 130, 159),  # 2: within 2 px of the right border
        rect(50, 60, 50, 60),    # 3: too small, 100 px
        rect(5, 115, 5, 155),    # 4: too large, 16500 px > 0.25 * 19200
        rect(50, 54, 5, 155),    # 5: too elongated, 4 x 150
        rect(75, 110, 100, 130),  # 6: 30 x 35 but only 5 of 35 rows have depth
        np.zeros((H, W), bool),  # 7: empty
        rect(80, 110, 20, 50),   # 8: good, 900 px
    ])
    kept = filter_masks(masks, depth, MaskFilter())
    assert kept.dtype == np.int64
    np.testing.assert_array_equal(kept, [0, 8])


def test_filter_thresholds_are_inclusive_and_border_zero_keeps_edges():
    depth = np.full((H, W), 2.0, dtype=np.float32)
    masks = np.stack([rect(0, 20, 0, 20), rect(50, 60, 50, 90)])  # corner; 10 x 40
    np.testing.assert_array_equal(filter_masks(masks, depth, MaskFilter(min_area=100)), [1])
    np.testing.assert_array_equal(
        filter_masks(masks, depth, MaskFilter(min_area=400, border=0)), [0, 1])
    np.testing.assert_array_equal(filter_masks(masks, depth, MaskFilter(min_area=401)), [])
    np.testing.assert_array_equal(
        filter_masks(masks, depth, MaskFilter(min_area=0, max_elongation=3.9)), [])
    np.testing.assert_array_equal(
        filter_masks(masks, depth, MaskFilter(min_area=0, max_elongation=4.1)), [1])


def test_filter_accepts_no_masks():
    out = filter_masks(np.zeros((0, H, W), bool), np.ones((H, W), np.float32), MaskFilter())
    assert out.shape == (0,) and out.dtype == np.int64


@settings(max_examples=150, deadline=None)
@given(st.integers(0, H - 1), st.integers(1, H), st.integers(0, W - 1), st.integers(1, W),
       st.integers(0, INVALID_MARGIN), st.integers(0, 5), st.integers(0, 1500),
       st.floats(0.01, 1.0), st.floats(1.0, 10.0), st.floats(0.0, 1.0),
       st.sampled_from([0, INVALID_MARGIN]))
def test_filter_on_rectangles_matches_the_rules(r0, h, c0, w, holes, border, min_area,
                                                max_share, max_elong, min_depth_share,
                                                invalid_margin):
    """For a rectangle every rule has a closed form: its principal standard deviations (of the
    pixels as unit squares) are in the ratio of its sides; `holes` columns from the left of the
    image have no depth, and with `invalid_margin` > 0 they are part of the image border."""
    h, w = min(h, H - r0), min(w, W - c0)
    mask = rect(r0, r0 + h, c0, c0 + w)
    depth = np.full((H, W), 3.0, dtype=np.float32)
    depth[:, :holes] = 0.0
    area = h * w
    with_depth = h * max(0, c0 + w - max(c0, holes))
    elongation = max(h, w) / min(h, w)
    # Stay away from ties. The elongation is computed from the sample covariance (n - 1), which
    # differs from the ratio of the sides by about 1 / area (a lot for a few pixels).
    assume(abs(elongation - max_elong) > (0.02 if area >= 50 else 0.5) * max_elong)
    assume(abs(with_depth - min_depth_share * area) > 1e-6)
    assume(abs(area - max_share * H * W) > 1e-6)
    f = MaskFilter(min_area=min_area, max_area_share=max_share, border=border,
                   max_elongation=max_elong, min_depth_share=min_depth_share,
                   invalid_margin=invalid_margin)
    # the left border is the last column without depth when those columns count as the edge
    left = max(holes - 1, 0) if invalid_margin else 0
    expected = ((border == 0 or (r0 >= border and c0 >= left + border and r0 + h <= H - border
                                 and c0 + w <= W - border))
                and min_area <= area <= max_share * H * W
                and with_depth >= min_depth_share * area
                and elongation <= max_elong)
    kept = filter_masks(mask[None], depth, f)
    assert kept.tolist() == ([0] if expected else [])


def test_filter_rejects_bad_masks():
    depth = np.ones((H, W), np.float32)
    for bad in (np.zeros((1, H, W), np.uint8), np.zeros((H, W), bool),
                np.zeros((1, H + 1, W), bool), [[[True]]]):
        with pytest.raises(DataError, match="masks"):
            filter_masks(bad, depth, MaskFilter())


def random_masks(rng: np.random.Generator, shape: tuple[int, int], k: int) -> np.ndarray:
    """(k, H, W) disjoint masks: blobs of random sizes and shapes (a label image cut up)."""
    labels = np.zeros(shape, np.int32)
    for i in range(1, k + 1):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        a, b = rng.integers(1, shape[0] // 2), rng.integers(1, shape[1] // 2)
        rr, cc = np.ogrid[:shape[0], :shape[1]]
        labels[((rr - r) / a) ** 2 + ((cc - c) / b) ** 2 <= 1] = i
    return labels[None] == np.arange(1, k + 1)[:, None, None]


@pytest.mark.parametrize("seed", range(6))
def test_filter_paths_agree(seed):
    """The compiled pass over the stack (width a multiple of 8, C order) and the per-mask path
    (any other stack), and `filter_labels` on the label image, keep the same masks."""
    rng = np.random.default_rng(seed)
    for shape in ((120, 160), (97, 131)):
        masks = random_masks(rng, shape, 12)
        depth = np.where(rng.random(shape) < 0.8, 2.0, 0.0).astype(np.float32)
        depth[:, :rng.integers(0, 20)] = 0.0  # a band without depth along the left edge
        labels = (masks * np.arange(1, 13)[:, None, None]).sum(axis=0)
        for f in (MaskFilter(min_area=30, min_depth_share=0.7, max_elongation=3.0),
                  MaskFilter(min_area=0, border=0), MaskFilter(border=4, invalid_margin=10)):
            kept = filter_masks(masks, depth, f)
            np.testing.assert_array_equal(filter_masks(np.asfortranarray(masks), depth, f),
                                          kept)
            np.testing.assert_array_equal(filter_labels(labels, 12, depth, f), kept)


def test_filter_labels_ignores_labels_past_count_and_refuses_junk():
    depth = np.full((H, W), 2.0, dtype=np.float32)
    labels = np.zeros((H, W), np.int64)
    labels[40:70, 40:70] = 1
    labels[80:110, 20:50] = 2
    labels[10:30, 100:130] = 7  # past count: no mask
    np.testing.assert_array_equal(filter_labels(labels, 2, depth, MaskFilter()), [0, 1])
    assert filter_labels(labels, 0, depth, MaskFilter()).shape == (0,)
    for bad, match in ((labels.astype(float), "labels"), (labels[:-1], "labels"),
                       (labels.tolist(), "labels")):
        with pytest.raises(DataError, match=match):
            filter_labels(bad, 2, depth, MaskFilter())
    for count in (-1, 2.0, None):
        with pytest.raises(DataError, match="count"):
            filter_labels(labels, count, depth, MaskFilter())
    with pytest.raises(DataError, match="depth_m"):
        filter_labels(labels, 2, depth.tolist(), MaskFilter())
    with pytest.raises(DataError, match="depth_m"):
        filter_masks(np.zeros((1, H, W), bool), depth[None], MaskFilter())


def labelled_depth_border(valid: np.ndarray, margin: int) -> np.ndarray:
    """`depth_border` as first written: every region without depth labelled, with its area."""
    H_, W_ = valid.shape
    edge = np.zeros((H_, W_), dtype=bool)
    edge[0], edge[-1], edge[:, 0], edge[:, -1] = True, True, True, True
    if margin == 0:
        return edge
    near = np.ones((H_, W_), dtype=bool)
    near[margin:H_ - margin, margin:W_ - margin] = False
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        (~valid).view(np.uint8), connectivity=8)
    reaches = np.zeros(count, dtype=bool)
    reaches[labels[edge]] = True
    inside = np.bincount(labels[near], minlength=count)
    band = reaches & (2 * inside > stats[:, cv2.CC_STAT_AREA])
    band[0] = False
    return edge | (band[labels] & near)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 60), st.integers(1, 60),
       st.floats(0.0, 1.0), st.integers(0, 25), st.booleans())
def test_depth_border_matches_labelling_every_region(seed, rows, cols, holes, margin, blobs):
    """The flood fill from the edge finds the regions that labelling them all finds, on noise
    (many small regions, runs that join diagonally) and on blobs (a few large ones)."""
    rng = np.random.default_rng(seed)
    missing = rng.random((rows, cols)) < holes
    if blobs:
        missing = cv2.dilate(missing.view(np.uint8), np.ones((5, 5), np.uint8)).view(bool)
    np.testing.assert_array_equal(depth_border(~missing, margin),
                                  labelled_depth_border(~missing, margin))


@pytest.mark.parametrize("kwargs", [
    {"min_area": -1}, {"min_area": 10.5}, {"min_area": True}, {"border": -1}, {"border": 1.5},
    {"max_area_share": 0.0}, {"max_area_share": 1.5}, {"max_elongation": 0.5},
    {"min_depth_share": -0.1}, {"min_depth_share": 1.1},
])
def test_bad_mask_filter_raises_config_error(kwargs):
    with pytest.raises(ConfigError, match=next(iter(kwargs))):
        MaskFilter(**kwargs)


SIZE_CAPS = [(MaskFilter, "border", MAX_BORDER, "MAX_BORDER"),
             (DepthSegmenterParams, "max_planes", MAX_PLANES, "MAX_PLANES"),
             (DepthSegmenterParams, "ransac_iterations", MAX_RANSAC_ITERATIONS,
              "MAX_RANSAC_ITERATIONS")]


@pytest.mark.parametrize(("cls", "name", "limit", "limit_name"), SIZE_CAPS,
                         ids=[name for _, name, _, _ in SIZE_CAPS])
@settings(max_examples=30, deadline=None)
@given(value=st.one_of(st.integers(0, 2 * MAX_RANSAC_ITERATIONS), st.integers(0, 2**80)))
def test_sizes_the_segmenter_allocates_by_are_at_most_their_limit(cls, name, limit, limit_name,
                                                                    value):
    """The border's dilation kernel, the planes removed and the RANSAC hypotheses drawn: an
    int up to its limit, refused beyond it."""
    if value <= limit:
        assert getattr(cls(**{name: value}), name) == value
        return
    with pytest.raises(ConfigError, match=rf"^{cls.__name__}\.{name} = {value}: must be an int "
                                          rf"in \[0, {limit}\].*\({limit_name}\)$"):
        cls(**{name: value})


# ---------------------------------------------------------------------------------------------
# the coarser grid of wide images


def test_wide_images_are_segmented_on_a_coarser_grid():
    assert DepthSegmenter(CAMERA).step == 2
    assert DepthSegmenter(PinholeCamera.from_fov(1280, 960, 87)).step == 4
    assert DepthSegmenter(PinholeCamera.from_fov(400, 300, 87)).step == 1
    assert DepthSegmenter(CAMERA, params=DepthSegmenterParams(work_width=0)).step == 1
    assert DepthSegmenter(CAMERA, params=DepthSegmenterParams(work_width=640)).step == 1


@pytest.mark.parametrize("seed", range(4))
def test_coarse_grid_masks_match_objects_as_well_as_full_resolution(seed):
    """On the grid of every second row and column, with labels brought back to full
    resolution by depth, each unoccluded object's best mask matches it (IoU) within 0.02 of
    the full-resolution segmenter's, with and without depth noise."""
    rng = np.random.default_rng(100 + seed)
    scene = random_room(rng, 6)
    full = DepthSegmenter(CAMERA, 1.0, DepthSegmenterParams(work_width=0))
    coarse = DepthSegmenter(CAMERA, 1.0)
    checked, failures = 0, []
    for p in range(2):
        T = camera_pose(*(free_pose(rng, scene) if p == 0 else
                          pose_facing(rng, scene, int(rng.integers(len(scene))), (1.0, 5.0))))
        objects = None
        for noise in (0.0, 0.0025):
            frame = render(scene, T, CAMERA, depth_noise=noise, rng=rng)
            at_full = full.segment(None, frame.depth)
            at_coarse = coarse.segment(None, frame.depth)
            if objects is None:  # the noise changes no pixel's instance, nor which have depth
                objects = unoccluded_objects(scene, T, frame)
            for k in objects:
                gt = frame.instance == k + 1
                best_full = max((iou(m, gt) for m in at_full), default=0.0)
                best_coarse = max((iou(m, gt) for m in at_coarse), default=0.0)
                checked += 1
                if best_coarse < best_full - 0.02:
                    failures.append(f"pose {p}, noise {noise}: object {k} "
                                    f"({np.count_nonzero(gt)} px) IoU {best_coarse:.3f} on the "
                                    f"grid, {best_full:.3f} at full resolution")
    assert checked >= 2
    assert not failures, "\n".join(failures)


def test_coarse_grid_masks_do_not_take_the_background_behind_their_object():
    """A box 1.5 m in front of a wall: no pixel of its mask is wall (the grid pixels on its
    outline cover wall pixels too, which the depth check gives back)."""
    scene = RgbdScene([[5.0, 4.0]], [0.5], [1.0], [False], [0.4], walls=room_walls(*ROOM))
    T = camera_pose(3.5, 4.0, 0.0)
    frame = render(scene, T, CAMERA)
    masks = DepthSegmenter(CAMERA, 1.0).segment(None, frame.depth)
    gt = frame.instance == 1
    best = masks[int(np.argmax([iou(m, gt) for m in masks]))]
    assert iou(best, gt) > 0.97
    assert not (best & ~gt).any()


@pytest.mark.parametrize("shape", [(48, 64), (45, 67), (480, 640)])
@pytest.mark.parametrize("k", [1, 3, 5])
def test_ransac_sample_is_the_full_resolution_median(shape, k):
    """RANSAC's points are the median-filtered image's (OpenCV's medianBlur, replicated border)
    at every ransac_stride-th pixel, as the full-resolution segmenter samples them: the same
    frame gives the same planes on the coarse grid."""
    rng = np.random.default_rng(k)
    z = np.where(rng.random(shape) < 0.8, rng.uniform(0.5, 6.0, shape), 0.0).astype(np.float32)
    for stride in (1, 3, 8):
        expected = (cv2.medianBlur(z, k) if k > 1 else z)[::stride, ::stride]
        np.testing.assert_array_equal(_sampled_median(z, stride, k, _median_network(k)),
                                      expected)


def test_more_than_255_masks():
    """300 boxes before a wall: 300 masks (the label image holds more than a byte), each its
    box, and the filters keep them all."""
    depth = np.full(CAMERA.shape, 4.0, dtype=np.float32)
    for r in range(15):
        for c in range(20):
            depth[32 * r + 6:32 * r + 26, 32 * c + 6:32 * c + 26] = 2.0
    segmenter = DepthSegmenter(CAMERA, 1.0, DepthSegmenterParams(max_planes=0))
    masks = segmenter.segment(None, depth)
    labels, count = segmenter.label(None, depth)
    assert count == masks.shape[0] == 300 and labels.dtype == np.int32
    assert masks.sum(axis=(1, 2)).tolist() == [400] * 300
    for i in (0, 255, 299):
        np.testing.assert_array_equal(masks[i], labels == i + 1)
    f = MaskFilter(min_area=100)
    np.testing.assert_array_equal(filter_masks(masks, depth, f), np.arange(300))
    np.testing.assert_array_equal(filter_labels(labels, count, depth, f), np.arange(300))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_segmenter_leaves_the_depth_image_alone(dtype):
    """Depth in float32 metres is read where it lies, not copied: it must come back as it
    went in, and so must depth with NaN and infinities (no return), which is copied."""
    rng = np.random.default_rng(3)
    scene = random_room(rng, 6)
    depth = render(scene, camera_pose(*pose_facing(rng, scene, 0)), CAMERA).depth.astype(dtype)
    depth[:5, :5] = np.nan
    depth[-5:, -5:] = np.inf
    before = depth.copy()
    masks = DepthSegmenter(CAMERA, 1.0).segment(None, depth)
    np.testing.assert_array_equal(depth, before)
    assert masks.shape[0] > 0 and not masks[:, :5, :5].any() and not masks[:, -5:, -5:].any()


# ---------------------------------------------------------------------------------------------
# input checks


@pytest.mark.parametrize("kwargs", [
    {"median": 4}, {"median": 7}, {"jump": -0.1}, {"jump": math.nan}, {"jump_per_m": math.inf},
    {"plane_distance": -1.0}, {"plane_distance_per_m2": "0.1"}, {"max_planes": -1},
    {"max_planes": 1.5}, {"ransac_iterations": -5}, {"ransac_stride": 0}, {"min_area": -1},
    {"seed": -1}, {"plane_share": 0.0}, {"plane_share": 1.5}, {"max_area_share": 0.0},
    {"max_area_share": 2.0}, {"depth_max": 0.1}, {"depth_min": 9.0},
    {"depth_max": math.inf}, {"depth_min": math.nan}, {"work_width": -1},
    {"work_width": 320.5}, {"work_width": True}, {"level_slice": -1}, {"level_slice": 2.5},
    {"level_slice": True}, {"level_slice": "24"},
])
def test_bad_segmenter_params_raise_config_error(kwargs):
    with pytest.raises(ConfigError, match=next(iter(kwargs))):
        DepthSegmenterParams(**kwargs)


SMALL = PinholeCamera.from_fov(64, 48, 87)


@pytest.mark.parametrize("depth, match", [
    (np.ones((48, 64), np.int32), "dtype"),
    (np.ones((48, 64), np.bool_), "dtype"),
    (np.ones((48, 64), np.complex64), "dtype"),
    (np.ones((64, 48), np.float32), "shape"),
    (np.ones((48, 64, 1), np.float32), "shape"),
    (-np.ones((48, 64), np.float32), "negative"),
    ([[1.0] * 64] * 48, "numpy"),
])
def test_bad_depth_raises_data_error(depth, match):
    with pytest.raises(DataError, match=match):
        DepthSegmenter(SMALL, 1.0).segment(None, depth)


@pytest.mark.parametrize("rgb, match", [
    (np.zeros((48, 64, 3), np.float32), "dtype"),
    (np.zeros((48, 64), np.uint8), "shape"),
    (np.zeros((48, 64, 4), np.uint8), "shape"),
    (np.zeros((47, 64, 3), np.uint8), "shape"),
    ("image", "numpy"),
])
def test_bad_rgb_raises_data_error(rgb, match):
    with pytest.raises(DataError, match=match):
        DepthSegmenter(SMALL, 1.0).segment(rgb, np.ones((48, 64), np.float32))


def test_check_rgb():
    rgb = np.zeros((4, 5, 3), np.uint8)
    assert check_rgb(rgb) is rgb
    assert check_rgb(rgb, (4, 5)) is rgb
    with pytest.raises(DataError, match=r"\(5, 4, 3\)"):
        check_rgb(rgb, (5, 4))


def test_pitched_camera_and_different_height_still_work():
    """The segmenter makes no assumption about the camera pose: a higher camera looking
    further down sees the same objects."""
    scene = RgbdScene([[4.0, 4.5], [5.0, 3.0]], [0.5, 0.4], [0.8, 1.0], [True, False], [0, 0.3],
                      walls=room_walls(*ROOM))
    T = camera_pose(1.5, 4.0, 0.0, T_body_camera(1.2, 20.0))
    checked, failures = check_frame(scene, T, DepthSegmenter(CAMERA, 1.0), MaskFilter())
    assert checked == 2
    assert not failures, "\n".join(failures)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 30), st.integers(1, 30), st.integers(0, 30), st.integers(1, 30),
       st.floats(0.3, 6.0), st.lists(st.floats(-1.0, 2.0), min_size=3, max_size=3),
       st.integers(1, 4), st.integers(0, 4))
def test_stands_in_front_needs_a_step_on_two_of_three_sides(r0, h, c0, w, depth, gaps, reach,
                                                            gap_px):
    """A rectangle at `depth`; the surface left of it, right of it and above it is `gaps`
    metres farther (or nearer), from `gap_px` pixels past the rectangle on: it stands in front
    iff at least two of those sides have a gap over the jump at its depth, within `reach`
    pixels and inside the image."""
    rows, cols = 40, 40
    h, w = min(h, rows - r0), min(w, cols - c0)
    jump, per_m = 0.05, 0.04
    threshold = jump + per_m * depth
    assume(all(abs(g - threshold) > 1e-3 for g in gaps))
    left_gap, right_gap, top_gap = gaps
    z = np.full((rows, cols), depth, dtype=np.float32)
    z[:max(r0 - gap_px, 0), c0:c0 + w] = depth + top_gap
    z[:, :max(c0 - gap_px, 0)] = depth + left_gap
    z[:, min(c0 + w + gap_px, cols):] = depth + right_gap
    z[r0:r0 + h, c0:c0 + w] = depth
    z = np.maximum(z, 0.0)  # a negative gap can reach below zero: no return there
    mask = np.zeros((rows, cols), dtype=bool)
    mask[r0:r0 + h, c0:c0 + w] = True
    within = gap_px < reach
    steps = [within and c0 - gap_px >= 1 and left_gap > threshold,
             within and c0 + w + gap_px < cols and right_gap > threshold,
             within and r0 - gap_px >= 1 and top_gap > threshold]
    assert stands_in_front(mask, z, jump, per_m, reach) == (sum(steps) >= 2)


def test_stands_in_front_refuses_junk_and_an_empty_mask_is_not_in_front():
    z = np.ones((4, 5), dtype=np.float32)
    assert not stands_in_front(np.zeros((4, 5), bool), z, 0.05, 0.04, 3)
    with pytest.raises(DataError, match=r"^stands_in_front: z must be"):
        stands_in_front(np.zeros((4, 5), bool), z.astype(int), 0.05, 0.04, 3)
    with pytest.raises(DataError, match=r"^stands_in_front: mask must be a \(4, 5\) bool"):
        stands_in_front(np.zeros((4, 6), bool), z, 0.05, 0.04, 3)
