"""Tests for tcaff_gtsam.mapping.fastsam: letterbox, decoding, NMS, masks and the model checks.

The models are tiny hand-built ONNX graphs with the FastSAM signature. The prototypes are the
input's red channel average-pooled onto the 4 x 4 pixel prototype cells, minus 0.5, in channel
0 (the other channels are zero), so an anchor with mask coefficient 0 = +1 segments whatever is
red inside its box. The anchors (output0) are constants the tests write.
"""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from onnx import TensorProto, helper, numpy_helper
from tcaff_gtsam.mapping.fastsam import FastSamOnnx, Letterbox, decode, letterbox, nms
from tcaff_gtsam.mapping.segment import MaskFilter, Segmenter

from tcaff_gtsam.errors import ConfigError, DataError, ModelError

S = 64  # input side of the fixed test model; prototypes are 16 x 16
H, W = 80, 160  # test image: letterboxed at S = 64 with scale 0.4, 16 rows of padding top/bottom

# Rectangles x0, y0, x1, y1 in image pixels, on multiples of 10 so that their edges land on
# prototype cell boundaries (one cell = 4 input pixels = 10 image pixels here).
R1 = (10, 10, 60, 40)  # 1500 px
R2 = (90, 40, 150, 70)  # 1800 px
R3 = (20, 50, 50, 70)  # 600 px
R4 = (60, 60, 80, 80)  # only a below-threshold anchor points here
BLUE = (100, 10, 140, 30)
DARK = (70, 10, 85, 30)  # nothing red nearby


def scene() -> np.ndarray:
    rgb = np.full((H, W, 3), 20, dtype=np.uint8)
    for x0, y0, x1, y1 in (R1, R2, R3, R4):
        rgb[y0:y1, x0:x1] = (255, 0, 0)
    x0, y0, x1, y1 = BLUE
    rgb[y0:y1, x0:x1] = (0, 0, 255)
    return rgb


def rect_mask(rect, shape=(H, W)) -> np.ndarray:
    x0, y0, x1, y1 = (round(v) for v in rect)
    m = np.zeros(shape, dtype=bool)
    m[y0:y1, x0:x1] = True
    return m


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return np.count_nonzero(a & b) / np.count_nonzero(a | b)


def anchor(rect, score: float, lb: Letterbox, coeff: float = 1.0, dx: float = 0.0) -> np.ndarray:
    """One output0 column for a box given in image pixels."""
    (x0, y0), (x1, y1) = lb.to_input(np.reshape(rect, (2, 2)))
    col = np.zeros(37, dtype=np.float32)
    col[:5] = ((x0 + x1) / 2 + dx, (y0 + y1) / 2, x1 - x0, y1 - y0, score)
    col[5] = coeff
    return col


def scene_anchors(lb: Letterbox) -> np.ndarray:
    """(37, A): R1, R2, R3 found; a near-duplicate of R1 (NMS), the blue and the dark box
    (empty masks), R4 below the threshold, and two all-zero anchors."""
    cols = [
        anchor(R1, 0.95, lb),
        anchor(R2, 0.90, lb),
        anchor(R3, 0.80, lb),
        anchor(R1, 0.85, lb, dx=0.5),
        anchor(BLUE, 0.92, lb),
        anchor(DARK, 0.88, lb),
        anchor(R4, 0.30, lb),
        np.zeros(37, np.float32),
        np.zeros(37, np.float32),
    ]
    return np.stack(cols, axis=1)


def build_model(path, anchors: np.ndarray, size: int | str = S, *, in_name="images",
                in_channels=3, out_names=("output0", "output1"), channels=32, pool=4):
    """Write a FastSAM-like model; `size` a string makes the input and prototype sizes
    symbolic."""
    symbolic = isinstance(size, str)
    in_shape = ["batch", in_channels, size, size] if symbolic else [1, in_channels, size, size]
    proto = ["batch", channels, "ph", "pw"] if symbolic else [1, channels, size // pool,
                                                                size // pool]
    select = np.zeros((1, channels, 1, 1), np.float32)
    select[0, 0] = 1.0
    inits = [
        numpy_helper.from_array(np.array([0], np.int64), "starts"),
        numpy_helper.from_array(np.array([1], np.int64), "ends"),
        numpy_helper.from_array(np.array([1], np.int64), "axes"),
        numpy_helper.from_array(np.array(0.5, np.float32), "half"),
        numpy_helper.from_array(select, "select"),
    ]
    nodes = [
        helper.make_node("Slice", [in_name, "starts", "ends", "axes"], ["red"]),
        helper.make_node("AveragePool", ["red"], ["pooled"], kernel_shape=[pool, pool],
                         strides=[pool, pool]),
        helper.make_node("Sub", ["pooled", "half"], ["centred"]),
        helper.make_node("Mul", ["centred", "select"], [out_names[1]]),
        helper.make_node("Constant", [], [out_names[0]],
                         value=numpy_helper.from_array(anchors[None].astype(np.float32))),
    ]
    graph = helper.make_graph(
        nodes, "fastsam_stub",
        [helper.make_tensor_value_info(in_name, TensorProto.FLOAT, in_shape)],
        [helper.make_tensor_value_info(out_names[0], TensorProto.FLOAT,
                                       [1, anchors.shape[0], anchors.shape[1]]),
         helper.make_tensor_value_info(out_names[1], TensorProto.FLOAT, proto)],
        inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


LB = Letterbox.fit(H, W, S)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    return build_model(tmp_path_factory.mktemp("fastsam") / "stub.onnx", scene_anchors(LB))


@pytest.fixture(scope="module")
def sam(model_path) -> FastSamOnnx:
    return FastSamOnnx(model_path, imgsz=S)


# --- the geometry the tests rely on ---------------------------------------------------------

def test_test_scene_letterbox():
    assert LB == Letterbox(size=64, scale=0.4, left=0, top=16, width=64, height=32)
    assert LB.proto_window() == (4, 12, 0, 16)


# --- detection ------------------------------------------------------------------------------

def test_is_a_segmenter(sam):
    assert isinstance(sam, Segmenter)


def test_finds_the_red_rectangles(sam):
    masks, boxes, scores = sam.segment_with_boxes(scene())
    # R1, R2, R3 by score. Gone: the duplicate of R1 (NMS), the blue and dark boxes (empty
    # masks) and R4 (score below conf).
    assert masks.shape == (3, H, W) and masks.dtype == np.bool_
    assert boxes.shape == (3, 4) and scores.shape == (3,)
    np.testing.assert_allclose(scores, [0.95, 0.90, 0.80], atol=1e-6)
    np.testing.assert_allclose(boxes, [R1, R2, R3], atol=1.0)
    for mask, box, rect in zip(masks, boxes, (R1, R2, R3), strict=True):
        assert iou(mask, rect_mask(rect)) >= 0.9
        assert not (mask & ~rect_mask(box)).any()
    # Away from the corners (rounded by the bilinear upsampling) the masks are exact.
    assert masks[0][12:38, 12:58].all() and masks[1][42:68, 92:148].all()


def test_segment_returns_the_masks(sam):
    depth = np.full((H, W), 1500, dtype=np.uint16)
    masks = sam.segment(scene(), depth)
    np.testing.assert_array_equal(masks, sam.segment_with_boxes(scene())[0])


def test_masks_are_cut_at_the_box_and_follow_the_prototypes_inside(tmp_path):
    half = (90, 40, 120, 70)  # the left half of R2
    loose = (5, 5, 65, 45)  # R1 with half a prototype cell of margin all round
    anchors = np.stack([anchor(half, 0.9, LB), anchor(loose, 0.8, LB)], axis=1)
    path = build_model(tmp_path / "m.onnx", anchors)
    masks, boxes, _ = FastSamOnnx(path, imgsz=S).segment_with_boxes(scene())
    assert masks.shape == (2, H, W)
    np.testing.assert_allclose(boxes, [half, loose], atol=1e-6)
    assert not masks[0][:, 120:].any()  # R2 continues to x = 150 but the box stops at 120
    assert iou(masks[0], rect_mask(half)) >= 0.9
    # Inside the loose box the edges are R1's, interpolated from the cells either side.
    assert not (masks[1][:10].any() or masks[1][40:].any() or masks[1][:, :10].any()
                or masks[1][:, 60:].any())
    assert iou(masks[1], rect_mask(R1)) >= 0.9
    # Only cells inside the box count for the area: half of R2 is 3 x 3 cells of 100 px,
    # though the cells right of it (x 120-130, red) are computed for the interpolation.
    for min_area, kept in ((900, [0.9]), (901, [])):
        sam = FastSamOnnx(path, imgsz=S, mask_filter=MaskFilter(min_area=min_area))
        scores = sam.segment_with_boxes(scene())[2]
        np.testing.assert_allclose(scores[scores > 0.85], kept, atol=1e-6)


def test_negative_coefficient_inverts_the_mask(tmp_path):
    box = (60, 0, 90, 50)  # dark except for a corner cell of R2 at x 90.. (outside) and R4
    path = build_model(tmp_path / "m.onnx", np.stack([anchor(box, 0.9, LB, coeff=-1)], axis=1))
    masks, _, _ = FastSamOnnx(path, imgsz=S).segment_with_boxes(scene())
    assert masks.shape == (1, H, W)
    assert iou(masks[0], rect_mask(box)) >= 0.9


def test_rgb_channel_order_matters(sam):
    # Swapping to BGR turns the red rectangles blue and the blue one red: only BLUE is found.
    masks, boxes, scores = sam.segment_with_boxes(np.ascontiguousarray(scene()[..., ::-1]))
    np.testing.assert_allclose(scores, [0.92], atol=1e-6)
    np.testing.assert_allclose(boxes, [BLUE], atol=1.0)
    assert iou(masks[0], rect_mask(BLUE)) >= 0.9


def test_nms_threshold_is_used(model_path):
    # At iou 0.99 the duplicate of R1 (IoU 0.975 with it) survives.
    masks, _, scores = FastSamOnnx(model_path, imgsz=S, iou=0.99).segment_with_boxes(scene())
    np.testing.assert_allclose(scores, [0.95, 0.90, 0.85, 0.80], atol=1e-6)
    assert iou(masks[2], rect_mask(R1)) >= 0.9


def test_conf_threshold_is_used(model_path):
    _, boxes, scores = FastSamOnnx(model_path, imgsz=S, conf=0.25).segment_with_boxes(scene())
    np.testing.assert_allclose(scores, [0.95, 0.90, 0.80, 0.30], atol=1e-6)
    np.testing.assert_allclose(boxes[3], R4, atol=1.0)
    _, _, scores = FastSamOnnx(model_path, imgsz=S, conf=0.9).segment_with_boxes(scene())
    np.testing.assert_allclose(scores, [0.95], atol=1e-6)


def test_max_det(model_path):
    _, _, scores = FastSamOnnx(model_path, imgsz=S, max_det=2).segment_with_boxes(scene())
    # The two best after NMS are R1 and BLUE; BLUE's mask is empty, so only R1 remains.
    np.testing.assert_allclose(scores, [0.95], atol=1e-6)


def test_area_filter_scales_prototype_cells_to_image_pixels(model_path):
    def scores(**kw):
        f = MaskFilter(**kw)
        return FastSamOnnx(model_path, imgsz=S, mask_filter=f).segment_with_boxes(scene())[2]

    # R3 (600 px) is smaller than 1000; R1 is exactly 15 cells of 10 x 10 px = 1500 px.
    np.testing.assert_allclose(scores(min_area=1000), [0.95, 0.90], atol=1e-6)
    np.testing.assert_allclose(scores(min_area=1500), [0.95, 0.90], atol=1e-6)
    np.testing.assert_allclose(scores(min_area=1501), [0.90], atol=1e-6)
    # R2 covers 1800 / 12800 = 0.14 of the image.
    np.testing.assert_allclose(scores(min_area=0, max_area_share=0.14), [0.95, 0.80],
                               atol=1e-6)


def test_area_filter_runs_before_upsampling(model_path, monkeypatch):
    seen = []
    upsample = FastSamOnnx._upsample

    def spy(logits, *args):
        seen.append(len(logits))
        return upsample(logits, *args)

    monkeypatch.setattr(FastSamOnnx, "_upsample", staticmethod(spy))
    f = MaskFilter(min_area=1000)
    FastSamOnnx(model_path, imgsz=S, mask_filter=f).segment_with_boxes(scene())
    # After NMS: R1, BLUE, R2, DARK, R3; BLUE and DARK are empty and R3 is small.
    assert seen == [2]


def test_nothing_detected(sam):
    masks, boxes, scores = sam.segment_with_boxes(np.zeros((H, W, 3), np.uint8))
    assert masks.shape == (0, H, W) and masks.dtype == np.bool_
    assert boxes.shape == (0, 4) and scores.shape == (0,)


def test_symbolic_input_size(tmp_path):
    # The same scene at S = 96 (scale 0.6, 24 px padding): cell edges no longer match the
    # rectangles, so the masks are approximate.
    lb = Letterbox.fit(H, W, 96)
    path = build_model(tmp_path / "dyn.onnx", scene_anchors(lb), size="S")
    masks, boxes, scores = FastSamOnnx(path, imgsz=96).segment_with_boxes(scene())
    np.testing.assert_allclose(scores, [0.95, 0.90, 0.80], atol=1e-6)
    np.testing.assert_allclose(boxes, [R1, R2, R3], atol=1.0)
    for mask, rect in zip(masks, (R1, R2, R3), strict=True):
        assert iou(mask, rect_mask(rect)) >= 0.8


def test_boxes_are_clipped_to_the_image(tmp_path):
    lb = LB
    beyond = (-20, -20, 60, 40)  # reaches into the padding above and left of the image
    path = build_model(tmp_path / "m.onnx", np.stack([anchor(beyond, 0.9, lb)], axis=1))
    masks, boxes, _ = FastSamOnnx(path, imgsz=S).segment_with_boxes(scene())
    np.testing.assert_allclose(boxes, [(0, 0, 60, 40)], atol=1e-6)
    assert iou(masks[0], rect_mask(R1)) >= 0.9


# --- letterbox, decode, NMS -----------------------------------------------------------------

@settings(max_examples=60, deadline=None)
@given(h=st.integers(1, 250), w=st.integers(1, 250), size=st.sampled_from([32, 64, 96, 160]),
       px=st.floats(-50, 300), py=st.floats(-50, 300))
def test_letterbox_places_the_image_where_the_mapping_says(h, w, size, px, py):
    # Ramps: red = kx * column index, green = ky * row index (integer steps, so exact).
    kx, ky = 255 // max(w - 1, 1), 255 // max(h - 1, 1)
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[..., 0] = kx * np.arange(w)[None, :]
    rgb[..., 1] = ky * np.arange(h)[:, None]
    rgb[..., 2] = 7
    tensor, lb = letterbox(rgb, size)
    assert tensor.shape == (1, 3, size, size) and tensor.dtype == np.float32
    np.testing.assert_allclose(lb.to_image(lb.to_input([px, py])), [px, py], atol=1e-9)
    # The image fills [left, left + width) x [top, top + height), centred; the rest is padding.
    content = np.zeros((size, size), bool)
    content[lb.top:lb.top + lb.height, lb.left:lb.left + lb.width] = True
    assert max(lb.width, lb.height) == size
    assert abs(2 * lb.left + lb.width - size) <= 1 and abs(2 * lb.top + lb.height - size) <= 1
    np.testing.assert_allclose(tensor[0, 2][content], 7 / 255, atol=1e-6)
    np.testing.assert_allclose(tensor[0][:, ~content], 114 / 255, atol=1e-6)
    # Inside, the ramps say which image pixel each input pixel shows: it is where `to_image`
    # maps it, within the rounding of the resized size (half an input pixel at the far edge)
    # and one uint8 level.
    tol = 0.55 + lb.scale / min(kx, ky)  # input pixels
    centres = np.arange(size) + 0.5
    cols = np.arange(lb.left, lb.left + lb.width)
    x_img = lb.to_image(np.column_stack([centres[cols], np.zeros(cols.size)]))[:, 0]
    inner = (x_img > 1) & (x_img < w - 1)
    value = tensor[0, 0, lb.top, cols[inner]] * 255 / kx
    x_in = lb.to_input(np.column_stack([value + 0.5, np.zeros(value.size)]))[:, 0]
    assert np.all(np.abs(x_in - centres[cols[inner]]) <= tol)
    rows = np.arange(lb.top, lb.top + lb.height)
    y_img = lb.to_image(np.column_stack([np.zeros(rows.size), centres[rows]]))[:, 1]
    inner = (y_img > 1) & (y_img < h - 1)
    value = tensor[0, 1, rows[inner], lb.left] * 255 / ky
    y_in = lb.to_input(np.column_stack([np.zeros(value.size), value + 0.5]))[:, 1]
    assert np.all(np.abs(y_in - centres[rows[inner]]) <= tol)


def test_decode_converts_centre_size_to_corners():
    out = np.zeros((37, 3), np.float32)
    out[:5, 0] = (10, 20, 4, 6, 0.7)
    out[:5, 1] = (30, 40, 8, 2, 0.2)
    out[:5, 2] = (50, 60, 2, 2, 0.6)
    out[5:, 0] = np.arange(32)
    boxes, scores, coeffs = decode(out, 0.5)
    np.testing.assert_allclose(boxes, [(8, 17, 12, 23), (49, 59, 51, 61)])
    np.testing.assert_allclose(scores, [0.7, 0.6], atol=1e-6)
    assert coeffs.shape == (2, 32) and coeffs.dtype == np.float32
    np.testing.assert_array_equal(coeffs[0], np.arange(32))


def _reference_nms(boxes, scores, thr):
    def pair_iou(a, b):
        iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
        ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
        union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - iw * ih
        return iw * ih / union if union > 0 else 0.0

    keep = []
    for i in sorted(range(len(boxes)), key=lambda i: -scores[i]):
        if all(pair_iou(boxes[i], boxes[j]) <= thr for j in keep):
            keep.append(i)
    return keep


box_st = st.tuples(st.integers(0, 40), st.integers(0, 40), st.integers(1, 30),
                   st.integers(1, 30)).map(lambda b: (b[0], b[1], b[0] + b[2], b[1] + b[3]))


@settings(max_examples=100, deadline=None)
@given(boxes=st.lists(box_st, max_size=25), thr=st.sampled_from([0.3, 0.5, 0.7, 0.9]),
       data=st.data())
def test_nms_matches_greedy_reference(boxes, thr, data):
    n = len(boxes)
    # Distinct scores so that the order is defined.
    scores = data.draw(st.permutations(list(range(n)))) if n else []
    scores = np.asarray(scores, dtype=float) / max(n, 1)
    boxes_a = np.asarray(boxes, dtype=float).reshape(-1, 4)
    keep = nms(boxes_a, scores, thr)
    assert keep.dtype == np.int64
    assert keep.tolist() == _reference_nms(boxes_a, scores, thr)
    assert nms(boxes_a, scores, thr, max_det=2).tolist() == keep[:2].tolist()


# --- configuration and model checks ---------------------------------------------------------

@pytest.mark.parametrize("kw", [
    {"imgsz": 100}, {"imgsz": 0}, {"imgsz": -32}, {"imgsz": True}, {"imgsz": 64.0},
    {"conf": 0}, {"conf": 1.5}, {"iou": 0.0}, {"iou": -0.1}, {"conf": "0.5"},
    {"mask_filter": {"min_area": 10}}, {"providers": ["NoSuchExecutionProvider"]},
    {"providers": []}, {"max_det": 0}, {"num_threads": 0},
])
def test_bad_parameters(model_path, kw):
    kw = {"imgsz": S, **kw}
    with pytest.raises(ConfigError, match=next(iter(kw.keys() - {"imgsz"}), "imgsz")):
        FastSamOnnx(model_path, **kw)


def test_model_path_must_be_a_path():
    with pytest.raises(ConfigError, match="model_path"):
        FastSamOnnx(42)


def test_missing_file(tmp_path):
    with pytest.raises(ModelError, match=r"not found.*ONNX file"):
        FastSamOnnx(tmp_path / "nope.onnx", imgsz=S)


def test_garbage_file(tmp_path):
    path = tmp_path / "garbage.onnx"
    path.write_bytes(b"this is not a protobuf \x00\xff" * 10)
    with pytest.raises(ModelError, match="expected an ONNX model"):
        FastSamOnnx(path, imgsz=S)


@pytest.mark.parametrize(("kw", "imgsz", "message"), [
    ({"in_name": "pixels"}, S, r"input 'images'.*found 'pixels'"),
    ({"in_channels": 1}, S, r"\[1, 3, S, S\].*\[1, 1, 64, 64\]"),
    ({"out_names": ("boxes", "protos")}, S, r"outputs named \['output0', 'output1'\]"),
    ({"channels": 31}, S, r"output1 of shape \[1, 32, S/4, S/4\].*found \[1, 31, 16, 16\]"),
    ({"pool": 8}, S, r"16 x 16 cells.*found \[1, 32, 8, 8\]"),
    ({}, 96, r"fixed at \[64, 64\] but imgsz = 96"),
])
def test_wrong_signature(tmp_path, kw, imgsz, message):
    path = build_model(tmp_path / "bad.onnx", scene_anchors(LB), **kw)
    with pytest.raises(ModelError, match=message):
        FastSamOnnx(path, imgsz=imgsz)


def test_output0_rows_checked(tmp_path):
    anchors = np.vstack([scene_anchors(LB), np.zeros((1, 9), np.float32)])  # 38 rows
    path = build_model(tmp_path / "bad.onnx", anchors)
    with pytest.raises(ModelError, match=r"output0 of shape \[1, 37, A\].*found \[1, 38, 9\]"):
        FastSamOnnx(path, imgsz=S)


def test_output_shapes_checked_at_run_time(tmp_path):
    # Symbolic prototype sizes pass the load check; the 8-pixel pooling gives S/8 cells.
    path = build_model(tmp_path / "dyn.onnx", scene_anchors(LB), size="S", pool=8)
    sam = FastSamOnnx(path, imgsz=S)
    with pytest.raises(ModelError, match=r"output1 of shape \(1, 32, 16, 16\).*\(1, 32, 8, 8\)"):
        sam.segment_with_boxes(scene())


# --- input checks ---------------------------------------------------------------------------

@pytest.mark.parametrize("rgb", [
    np.zeros((H, W, 3), np.float32), np.zeros((H, W), np.uint8), np.zeros((H, W, 4), np.uint8),
    np.zeros((0, W, 3), np.uint8), [[0, 0, 0]],
])
def test_bad_rgb(sam, rgb):
    with pytest.raises(DataError, match="rgb"):
        sam.segment_with_boxes(rgb)
    with pytest.raises(DataError, match="rgb"):
        sam.segment(rgb, np.zeros((H, W), np.uint16))


@pytest.mark.parametrize("depth", [
    np.zeros((H, W), np.int32), np.zeros((H, W + 1), np.uint16), np.zeros((H, W, 1), np.float32),
    np.zeros((W, H), np.float64), None,
])
def test_bad_depth(sam, depth):
    with pytest.raises(DataError, match="depth"):
        sam.segment(scene(), depth)


@pytest.mark.parametrize("dtype", [np.uint16, np.float32, np.float64])
def test_depth_dtypes_accepted(sam, dtype):
    assert sam.segment(scene(), np.zeros((H, W), dtype)).shape == (3, H, W)
