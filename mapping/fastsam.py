"""FastSAM instance segmentation through onnxruntime.

`FastSamOnnx` runs a FastSAM model exported to ONNX (the YOLOv8-seg export format) and
implements the `Segmenter` protocol of `segment.py`. The export has

- one input `images`, (1, 3, S, S) float32 in [0, 1], RGB, the image letterboxed into the
  square (see `Letterbox`);
- `output0`, (1, 37, A): per anchor the box centre x, y, width, height in input pixels, the
  score (already a probability) and 32 mask coefficients;
- `output1`, (1, 32, S/4, S/4): the mask prototypes. A mask's logits are its coefficients
  times the prototypes; the mask is where they are positive, inside the box.

Coordinates: image pixels have their origin at the top-left corner of the top-left pixel, x to
the right, y down, so pixel (row v, column u) covers [u, u + 1) x [v, v + 1) and its centre is
at (u + 0.5, v + 0.5). Input pixels (the letterboxed S x S square) and prototype cells (one
cell = 4 x 4 input pixels) use the same convention.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from tcaff_gtsam.errors import ConfigError, DataError, ModelError
from tcaff_gtsam.params import _int_at_least, _real, _require

from .camera import depth_in_metres
from .segment import MaskFilter, check_rgb

__all__ = ["FastSamOnnx", "Letterbox", "decode", "letterbox", "nms"]

_INPUT = "images"
_OUTPUTS = ("output0", "output1")
_N_COEFFS = 32
_N_ROWS = 4 + 1 + _N_COEFFS  # box, score, mask coefficients
_PROTO_STRIDE = 4  # input pixels per prototype cell
_PAD_VALUE = 114  # letterbox padding on the 0-255 scale, as in training


@dataclass(frozen=True)
class Letterbox:
    """Where an (h, w) image sits inside the square (size, size) network input.

    The image is scaled by `scale` (input pixels per image pixel) to (height, width) input
    pixels and placed with its top-left corner at input pixel (left, top); the rest is padding.
    """

    size: int
    scale: float
    left: int
    top: int
    width: int
    height: int

    @classmethod
    def fit(cls, h: int, w: int, size: int) -> Letterbox:
        """The letterbox of an (h, w) image in a (size, size) input (the YOLOv8 rule)."""
        scale = min(size / h, size / w)
        width = max(1, round(w * scale))  # a 1-pixel sliver of a huge image must not vanish
        height = max(1, round(h * scale))
        left = round((size - width) / 2 - 0.1)
        top = round((size - height) / 2 - 0.1)
        return cls(size, scale, left, top, width, height)

    def to_input(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) image pixel coordinates (x, y) -> input pixel coordinates."""
        xy = np.asarray(xy, dtype=float)
        return xy * self.scale + np.array([self.left, self.top], dtype=float)

    def to_image(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) input pixel coordinates (x, y) -> image pixel coordinates (not clipped)."""
        xy = np.asarray(xy, dtype=float)
        return (xy - np.array([self.left, self.top], dtype=float)) / self.scale

    def proto_window(self) -> tuple[int, int, int, int]:
        """(row0, row1, col0, col1): the prototype cells whose centres lie on the image, as
        half-open ranges; cropping to them drops the padding."""
        s = _PROTO_STRIDE

        def cells(start: int, length: int) -> tuple[int, int]:
            lo = math.ceil((start - s / 2) / s)
            hi = math.ceil((start + length - s / 2) / s)
            return lo, max(hi, lo + 1)

        r0, r1 = cells(self.top, self.height)
        c0, c1 = cells(self.left, self.width)
        return r0, r1, c0, c1


def letterbox(rgb: np.ndarray, size: int) -> tuple[np.ndarray, Letterbox]:
    """The network input for an image.

    Args:
        rgb: (h, w, 3) uint8, RGB.
        size: S, the side of the square input in pixels.

    Returns:
        (1, 3, S, S) float32 in [0, 1], RGB planes, and the `Letterbox` used.
    """
    h, w = rgb.shape[:2]
    lb = Letterbox.fit(h, w, size)
    resized = rgb
    if (lb.width, lb.height) != (w, h):
        resized = cv2.resize(rgb, (lb.width, lb.height), interpolation=cv2.INTER_LINEAR)
    tensor = np.full((1, 3, size, size), _PAD_VALUE / 255.0, dtype=np.float32)
    region = tensor[0, :, lb.top:lb.top + lb.height, lb.left:lb.left + lb.width]
    for plane, out in zip(cv2.split(resized), region, strict=True):  # faster than transposing
        np.multiply(plane, np.float32(1.0 / 255.0), out=out)
    return tensor, lb


def decode(output0: np.ndarray, conf: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The anchors scoring above `conf`.

    Args:
        output0: (37, A) float32, one column per anchor (see the module docstring).
        conf: score threshold in (0, 1].

    Returns:
        boxes (n, 4) float64 x0, y0, x1, y1 in input pixels; scores (n,) float64;
        coefficients (n, 32) float32.
    """
    idx = np.flatnonzero(output0[4] > conf)
    cx, cy, bw, bh = output0[:4, idx].astype(float)
    boxes = np.column_stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2])
    coeffs = np.ascontiguousarray(output0[5:, idx].T, dtype=np.float32)
    return boxes, output0[4, idx].astype(float), coeffs


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float, max_det: int | None = None
        ) -> np.ndarray:
    """Greedy non-maximum suppression.

    Args:
        boxes: (n, 4) x0, y0, x1, y1.
        scores: (n,).
        iou: a box is dropped when its IoU with a kept, higher-scoring box exceeds this.
        max_det: stop after this many kept boxes (None: no limit).

    Returns:
        (m,) int64 indices into `boxes`, by decreasing score.
    """
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    order = np.argsort(-np.asarray(scores, dtype=float), kind="stable")
    x0, y0, x1, y1 = boxes.T
    areas = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    limit = len(order) if max_det is None else max_det
    keep: list[int] = []
    while order.size and len(keep) < limit:
        i, rest = order[0], order[1:]
        keep.append(int(i))
        iw = np.maximum(np.minimum(x1[i], x1[rest]) - np.maximum(x0[i], x0[rest]), 0.0)
        ih = np.maximum(np.minimum(y1[i], y1[rest]) - np.maximum(y0[i], y0[rest]), 0.0)
        inter = iw * ih
        union = areas[i] + areas[rest] - inter
        overlap = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
        order = rest[overlap <= iou]
    return np.asarray(keep, dtype=np.int64)


def _pixel_span(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half-open index ranges of the pixels (or cells) whose centres lie in [lo, hi)."""
    return np.ceil(lo - 0.5).astype(np.int64), np.ceil(hi - 0.5).astype(np.int64)


def _dim(value) -> int | None:
    """A fixed dimension of an onnxruntime shape, or None if it is symbolic."""
    return value if isinstance(value, int) else None


def _check_image(rgb) -> np.ndarray:
    """`rgb` if it is a non-empty (H, W, 3) uint8 image; else DataError."""
    rgb = check_rgb(rgb)
    if rgb.size == 0:
        raise DataError(f"rgb has shape {rgb.shape}; expected a non-empty image")
    return rgb


def _describe(args) -> str:
    return ", ".join(f"{a.name!r} {list(a.shape)} {a.type}" for a in args) or "none"


class FastSamOnnx:
    """FastSAM (a YOLOv8-seg ONNX export) run through onnxruntime; a `Segmenter`.

    Args:
        model_path: the .onnx file.
        imgsz: S, the side of the square network input in pixels, a multiple of 32; must equal
            the model's if the model fixes it.
        conf: score threshold in (0, 1].
        iou: non-maximum suppression IoU threshold in (0, 1].
        mask_filter: if given, masks whose area is outside its [min_area, max_area_share] range
            are dropped early (estimated on the prototype grid); its other criteria are left to
            `segment.filter_masks`.
        providers: onnxruntime execution providers; default ["CPUExecutionProvider"].
        max_det: most detections kept per image (by score).
        num_threads: onnxruntime intra-op threads.

    Raises:
        ConfigError: a parameter out of range.
        ModelError: the file is missing, is not an ONNX model, or does not have the FastSAM
            signature.
    """

    def __init__(self, model_path, imgsz: int = 1024, conf: float = 0.5, iou: float = 0.9,
                 mask_filter: MaskFilter | None = None, providers: list[str] | None = None,
                 max_det: int = 300, num_threads: int = 2) -> None:
        o = "FastSamOnnx"

        def is_unit(v) -> bool:
            return _real(v) and 0 < v <= 1

        _require(_int_at_least(imgsz, 1) and imgsz % 32 == 0, o, "imgsz", imgsz,
                 "must be a positive multiple of 32 pixels")
        _require(is_unit(conf), o, "conf", conf, "must be in (0, 1]")
        _require(is_unit(iou), o, "iou", iou, "must be in (0, 1]")
        _require(mask_filter is None or isinstance(mask_filter, MaskFilter), o, "mask_filter",
                 mask_filter, "must be a MaskFilter or None")
        _require(_int_at_least(max_det, 1), o, "max_det", max_det, "must be an int > 0")
        _require(_int_at_least(num_threads, 1), o, "num_threads", num_threads,
                 "must be an int > 0")
        if providers is None:
            providers = ["CPUExecutionProvider"]
        available = ort.get_available_providers()
        _require(isinstance(providers, (list, tuple)) and len(providers) > 0
                 and all(p in available for p in providers), o, "providers", providers,
                 f"must be a non-empty list drawn from {available}")
        self.imgsz = int(imgsz)
        self.conf = float(conf)
        self.iou = float(iou)
        self.mask_filter = mask_filter
        self.max_det = int(max_det)
        if not isinstance(model_path, (str, os.PathLike)):
            raise ConfigError(f"{o}.model_path = {model_path!r}: must be a path")
        self.model_path = Path(model_path)
        self._session = self._load(list(providers), int(num_threads))
        self._check_signature()

    def _load(self, providers: list[str], num_threads: int) -> ort.InferenceSession:
        path = self.model_path
        if not path.is_file():
            raise ModelError(f"FastSAM model not found: expected an ONNX file at {path}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = num_threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3  # onnxruntime warns about unused initialisers etc.
        # Idle workers would otherwise spin and steal the cores the post-processing (and the
        # rest of the mapper) runs on.
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            return ort.InferenceSession(str(path), sess_options=options, providers=providers)
        except Exception as exc:  # onnxruntime raises assorted pybind error types
            raise ModelError(f"{path}: expected an ONNX model that onnxruntime can load; "
                             f"loading failed: {exc}") from exc

    def _check_signature(self) -> None:
        S, P = self.imgsz, self.imgsz // _PROTO_STRIDE
        where = str(self.model_path)
        inputs, outputs = self._session.get_inputs(), self._session.get_outputs()
        want_in = f"one input {_INPUT!r} of shape [1, 3, S, S] tensor(float)"
        if len(inputs) != 1 or inputs[0].name != _INPUT:
            raise ModelError(f"{where}: expected {want_in}; found {_describe(inputs)}")
        shape = list(inputs[0].shape)
        if (len(shape) != 4 or _dim(shape[0]) not in (None, 1)
                or _dim(shape[1]) not in (None, 3) or inputs[0].type != "tensor(float)"):
            raise ModelError(f"{where}: expected {want_in}; found {_describe(inputs)}")
        fixed = {d for d in (_dim(shape[2]), _dim(shape[3])) if d is not None}
        if fixed and fixed != {S}:
            raise ModelError(f"{where}: the model's input size is fixed at {shape[2:]} but "
                             f"imgsz = {S}; expected imgsz to equal the model's input size")
        by_name = {a.name: a for a in outputs}
        if not all(n in by_name for n in _OUTPUTS):
            raise ModelError(f"{where}: expected outputs named {list(_OUTPUTS)}; found "
                             f"{_describe(outputs)}")
        o0, o1 = list(by_name[_OUTPUTS[0]].shape), list(by_name[_OUTPUTS[1]].shape)
        if len(o0) != 3 or _dim(o0[1]) not in (None, _N_ROWS):
            raise ModelError(f"{where}: expected output0 of shape [1, {_N_ROWS}, A] (box, score "
                             f"and {_N_COEFFS} mask coefficients per anchor); found {o0}")
        if len(o1) != 4 or _dim(o1[1]) not in (None, _N_COEFFS):
            raise ModelError(f"{where}: expected output1 of shape [1, {_N_COEFFS}, S/4, S/4] "
                             f"(mask prototypes); found {o1}")
        if any(_dim(d) not in (None, P) for d in o1[2:]):
            raise ModelError(f"{where}: expected output1 prototypes of {P} x {P} cells "
                             f"(imgsz / 4) for imgsz = {S}; found {o1}")

    def _run(self, tensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(37, A) anchors and (32, S/4, S/4) prototypes for one (1, 3, S, S) input."""
        try:
            out0, out1 = self._session.run(list(_OUTPUTS), {_INPUT: tensor})
        except Exception as exc:  # onnxruntime raises assorted pybind error types
            raise ModelError(f"{self.model_path}: onnxruntime failed to run the model: "
                             f"{exc}") from exc
        P = self.imgsz // _PROTO_STRIDE
        if out0.ndim != 3 or out0.shape[:2] != (1, _N_ROWS):
            raise ModelError(f"{self.model_path}: expected output0 of shape (1, {_N_ROWS}, A); "
                             f"the model produced {out0.shape}")
        if out1.shape != (1, _N_COEFFS, P, P):
            raise ModelError(f"{self.model_path}: expected output1 of shape "
                             f"(1, {_N_COEFFS}, {P}, {P}); the model produced {out1.shape}")
        return (np.asarray(out0[0], dtype=np.float32), np.asarray(out1[0], dtype=np.float32))

    def segment_with_boxes(self, rgb: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Instance masks, boxes and scores of one image.

        Args:
            rgb: (H, W, 3) uint8, RGB order.

        Returns:
            masks (k, H, W) bool, each non-empty and zero outside its box; boxes (k, 4) float64
            x0, y0, x1, y1 in image pixels, clipped to the image; scores (k,) float64 in
            (conf, 1], non-increasing.

        Raises:
            DataError: `rgb` is not a non-empty (H, W, 3) uint8 array.
            ModelError: the model's outputs have unexpected shapes.
        """
        rgb = _check_image(rgb)
        tensor, lb = letterbox(rgb, self.imgsz)
        out0, out1 = self._run(tensor)
        return self._postprocess(out0, out1, lb, rgb.shape[:2])

    def segment(self, rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """(k, H, W) bool masks of one frame; `depth` ((H, W) uint16/float32/float64, see
        `camera.py`) is only checked, FastSAM uses colour alone."""
        rgb = _check_image(rgb)
        depth_in_metres(depth, 1.0, rgb.shape[:2])
        return self.segment_with_boxes(rgb)[0]

    def _postprocess(self, out0: np.ndarray, out1: np.ndarray, lb: Letterbox,
                     shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Detections of one image from the raw outputs ((37, A), (32, S/4, S/4))."""
        H, W = shape
        boxes_in, scores, coeffs = decode(out0, self.conf)
        keep = nms(boxes_in, scores, self.iou, self.max_det)
        scores, coeffs = scores[keep], coeffs[keep]
        corners = lb.to_image(boxes_in[keep].reshape(-1, 2, 2)).reshape(-1, 4)
        boxes = np.clip(corners, 0, [W, H, W, H])
        patches, positive = _box_logits(coeffs, out1, boxes, lb)
        if self.mask_filter is not None:
            area = positive * (_PROTO_STRIDE / lb.scale) ** 2  # image pixels per cell
            ok = np.flatnonzero(self.mask_filter.area_ok(area, H * W))
            boxes, scores, patches = boxes[ok], scores[ok], [patches[i] for i in ok]
        masks, nonempty = self._upsample(patches, boxes, lb, (H, W))
        return masks, boxes[nonempty], scores[nonempty]

    @staticmethod
    def _upsample(patches: list[_Patch | None], boxes: np.ndarray, lb: Letterbox,
                  shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear upsampling of each box's logits to the image pixels in the box,
        thresholded at 0.

        The pixels are interpolated straight from the prototype cells with the exact letterbox
        geometry (no rounding of the padding crop to whole cells).

        Args:
            patches: per box, its logits on the prototype cells (see `_box_logits`).
            boxes: (k, 4) x0, y0, x1, y1 image pixels, inside the image.

        Returns:
            (k', H, W) bool masks of the non-empty ones and the (k,) bool selecting them.
        """
        H, W = shape
        u0, u1 = _pixel_span(boxes[:, 0], boxes[:, 2])
        v0, v1 = _pixel_span(boxes[:, 1], boxes[:, 3])
        step = lb.scale / _PROTO_STRIDE  # prototype cells per image pixel
        done = []
        nonempty = np.zeros(len(boxes), dtype=bool)
        for i, patch in enumerate(patches):
            if patch is None:
                continue
            # Maps a mask pixel index to a patch cell index (both count centres at integers).
            tx = ((u0[i] + 0.5) * lb.scale + lb.left) / _PROTO_STRIDE - 0.5 - patch.col
            ty = ((v0[i] + 0.5) * lb.scale + lb.top) / _PROTO_STRIDE - 0.5 - patch.row
            M = np.array([[step, 0.0, tx], [0.0, step, ty]])
            mask = cv2.warpAffine(patch.logits, M, (int(u1[i] - u0[i]), int(v1[i] - v0[i])),
                                  flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_REPLICATE) > 0
            if mask.any():
                nonempty[i] = True
                done.append((i, mask))
        masks = np.zeros((len(done), H, W), dtype=bool)
        for j, (i, mask) in enumerate(done):
            masks[j, v0[i]:v1[i], u0[i]:u1[i]] = mask
        return masks, nonempty


@dataclass(frozen=True)
class _Patch:
    """A box's mask logits on a block of prototype cells: (h, w) float32 whose [0, 0] is cell
    (row, col) of the full S/4 x S/4 grid."""

    logits: np.ndarray
    row: int
    col: int


def _box_logits(coeffs: np.ndarray, protos: np.ndarray, boxes: np.ndarray, lb: Letterbox
                ) -> tuple[list[_Patch | None], np.ndarray]:
    """Each box's mask logits on the prototype cells it needs, and its positive cells.

    Only the cells under a box (and the neighbours its pixels interpolate from) are computed:
    the work and memory then scale with the boxes' areas, not with k times the grid.

    Args:
        coeffs: (k, 32) mask coefficients.
        protos: (32, S/4, S/4) prototypes.
        boxes: (k, 4) x0, y0, x1, y1 image pixels, inside the image.

    Returns:
        per box a `_Patch` (None if the box holds no pixel centre), within the cells whose
        centres lie on the image (the padding is cropped); and (k,) int64 the number of
        positive cells whose centres lie inside the box.
    """
    r0, r1, c0, c1 = lb.proto_window()

    def cells(lo, hi, offset, first, last):
        """Per box the half-open cell range to compute, and the cells with centres inside."""
        edge_lo = (lo * lb.scale + offset) / _PROTO_STRIDE  # cells cover [j, j + 1)
        edge_hi = (hi * lb.scale + offset) / _PROTO_STRIDE
        inside = _pixel_span(edge_lo, edge_hi)
        p0, p1 = _pixel_span(lo, hi)
        # Pixel centres in cell-index coordinates; each reads the cells either side.
        centre_lo = ((p0 + 0.5) * lb.scale + offset) / _PROTO_STRIDE - 0.5
        centre_hi = ((p1 - 0.5) * lb.scale + offset) / _PROTO_STRIDE - 0.5
        need_lo = np.minimum(inside[0], np.floor(centre_lo).astype(np.int64))
        need_hi = np.maximum(inside[1], np.floor(centre_hi).astype(np.int64) + 2)
        need = np.clip(need_lo, first, last - 1), np.clip(need_hi, first + 1, last)
        return need, (np.clip(inside[0], first, last), np.clip(inside[1], first, last)), p1 > p0

    (x_lo, x_hi), (xi_lo, xi_hi), has_x = cells(boxes[:, 0], boxes[:, 2], lb.left, c0, c1)
    (y_lo, y_hi), (yi_lo, yi_hi), has_y = cells(boxes[:, 1], boxes[:, 3], lb.top, r0, r1)
    patches: list[_Patch | None] = []
    positive = np.zeros(len(boxes), dtype=np.int64)
    for i in range(len(boxes)):
        if not (has_x[i] and has_y[i]):
            patches.append(None)
            continue
        block = protos[:, y_lo[i]:y_hi[i], x_lo[i]:x_hi[i]]
        logits = np.einsum("c,chw->hw", coeffs[i], block)
        inside = logits[yi_lo[i] - y_lo[i]:yi_hi[i] - y_lo[i],
                        xi_lo[i] - x_lo[i]:xi_hi[i] - x_lo[i]]
        positive[i] = np.count_nonzero(inside > 0)
        patches.append(_Patch(logits, int(y_lo[i]), int(x_lo[i])))
    return patches, positive
