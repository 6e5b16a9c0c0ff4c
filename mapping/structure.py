"""Room structure: the rules by which `DepthSegmenter` tells floor, ceiling and walls from
objects.

The rules themselves are listed in `DepthSegmenter`'s docstring; this module holds their parts:
the seeded RANSAC search for dominant planes (`_find_planes`), a plane's band of pixels, the
wall parts of a wall's band (`_wall_parts`), the slices of a level band through objects beside
it, and whether a mask `stands_in_front` of what is around it (which the lifter also asks of
a wall-like cloud). The hot loops are numba kernels (at the end of the module, cached on disk;
`segment._compile_kernels` runs each once).
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np

from tcaff_gtsam.errors import DataError

from .depth_grid import _FAST

__all__ = ["stands_in_front"]

#: sample points on which each RANSAC hypothesis is scored
_RANSAC_SCORED = 1000


def stands_in_front(mask: np.ndarray, z: np.ndarray, jump: float, jump_per_m: float,
                    reach: int) -> bool:
    """Whether a mask stands in front of what is around it, as an object's face does and a
    wall does not: on at least two of its left, right and top sides, the surface seen just
    past it is farther by a depth jump. A side has the step when, in at least half of the
    image rows (columns, for the top) the mask spans, the farthest depth within `reach` pixels
    past its outermost pixel is farther than that pixel's by more than
    jump + jump_per_m * depth. A cabinet against a wall shows the wall beside it and above it
    (in a room's corner, on one side and above it); a wall ends at the image border, in a
    corner or at the ceiling (no step), and has a step on one side at most (a door, a corner
    jutting into the room).

    Args:
        mask: (H, W) bool (an empty one stands in front of nothing).
        z: (H, W) metres, 0 = no return (never farther).
        jump: metres; jump_per_m: metres per metre of depth; reach: pixels (>= 1).

    Raises:
        DataError: z not an (H, W) float array, or mask not an (H, W) bool array.
    """
    if not (isinstance(z, np.ndarray) and z.ndim == 2 and z.dtype.kind == "f"):
        got = f"{z.shape} {z.dtype}" if isinstance(z, np.ndarray) else type(z).__name__
        raise DataError(f"stands_in_front: z must be an (H, W) float array of metres, got {got}")
    if not (isinstance(mask, np.ndarray) and mask.dtype == np.bool_ and mask.shape == z.shape):
        got = f"{mask.shape} {mask.dtype}" if isinstance(mask, np.ndarray) else type(mask).__name__
        raise DataError(f"stands_in_front: mask must be a {z.shape} bool array, got {got}")
    if not mask.any():
        return False
    left, right = _stepped_ends(mask, z, jump, jump_per_m, reach)
    top, _ = _stepped_ends(mask.T, z.T, jump, jump_per_m, reach)
    return left + right + top >= 2


def _stepped_ends(mask: np.ndarray, z: np.ndarray, jump: float, jump_per_m: float,
                  reach: int) -> tuple[bool, bool]:
    """Whether the first and whether the last pixels of a non-empty mask's rows have a depth
    step past them (see `stands_in_front`) in at least half of those rows."""
    W = mask.shape[1]
    rows = np.flatnonzero(mask.any(axis=1))
    sub = mask[rows]
    first = sub.argmax(axis=1)
    last = W - 1 - sub[:, ::-1].argmax(axis=1)
    beyond = np.arange(1, reach + 1)
    stepped = []
    for end, cols in ((first, first[:, None] - beyond), (last, last[:, None] + beyond)):
        inside = (cols >= 0) & (cols < W)
        farthest = np.where(inside, z[rows[:, None], np.clip(cols, 0, W - 1)], 0.0).max(axis=1)
        own = z[rows, end]
        steps = (own > 0) & (farthest - own > jump + jump_per_m * own)
        stepped.append(bool(2 * np.count_nonzero(steps) >= rows.size))
    return stepped[0], stepped[1]


def _find_planes(pts: np.ndarray, tol: np.ndarray, up: np.ndarray, *, max_planes: int,
                 iterations: int, seed: int, plane_share: float, level_plane_share: float,
                 level_tolerance_deg: float) -> list[tuple[np.ndarray, float, bool]]:
    """The dominant planes among sampled points, in the order RANSAC finds them: (unit normal
    (3,), offset, level) each, of the plane normal . p + offset = 0.

    RANSAC (`iterations` hypotheses a round, drawn from a generator seeded with `seed`) finds
    one plane after another among the points no plane found so far holds, for at most
    max_planes + 3 rounds, until a round finds none holding min(plane_share,
    level_plane_share) of the points. A plane is level when its normal lies within
    `level_tolerance_deg` of the gravity axis (`up`, (3,) the up direction in the optical
    frame); it is one of the dominant planes when it holds `level_plane_share` of the points
    if level, else `plane_share`.

    Args:
        pts: (m, 3) float metres in the optical frame; reordered in place.
        tol: (m,) metres, how far from a plane each point may lie and be held by it;
            reordered with pts.
    """
    n_sampled = pts.shape[0]
    need = min(plane_share, level_plane_share) * n_sampled
    cos_level = math.cos(math.radians(level_tolerance_deg))
    rng = np.random.default_rng(seed)
    planes = []  # (normal, offset, level) of the planes holding their share of the sample
    n = n_sampled  # pts[:n] are the points no plane found so far holds
    for _ in range(max_planes + 3):
        if n < max(need, 3):
            break
        tri = rng.integers(n, size=(iterations, 3))
        # hypotheses are scored on a random subset: ranking them needs far fewer points
        scored = (rng.choice(n, _RANSAC_SCORED, replace=False) if n > _RANSAC_SCORED
                  else np.arange(n))
        normal, offset, n_in, found = _ransac_round(pts, tol, n, tri, scored)
        if not found or n_in < need:
            break
        level = abs(float(normal @ up)) >= cos_level
        if n_in >= (level_plane_share if level else plane_share) * n_sampled:
            planes.append((normal, offset, level))
        n -= n_in
    return planes


def _wall_parts(band: np.ndarray, z: np.ndarray, border: np.ndarray,
               jumps: tuple[np.ndarray, np.ndarray], ceiling: np.ndarray, out: np.ndarray,
               enough: float, *, min_extent: float, fx: float, fy: float, reach: int,
               seam: int, jump: float, jump_per_m: float) -> bool:
    """Whether the wall parts of a (not level) plane's band of pixels hold `enough` pixels,
    and if so adds them to `out` ((h, w) bool).

    The wall parts are the 8-connected parts of `band` ((h, w) bool) that are wall, not an
    object's face: those that reach `border` ((h, w) bool, the image edge and the band
    without depth along it, grown by one pixel); those seen only past nearer things,
    holding pixels on the far side of depth jumps but none on the near side (`jumps`, both
    (h, w) bool), like a piece of wall seen under a chair; and those that span `min_extent`
    metres (2D box in pixels times mean depth over the focal lengths fx, fy in pixels) unless
    they stand in front of what is around them (`stands_in_front`, with jump, jump_per_m and
    reach) and do not meet `ceiling` ((h, w) bool, the removed level planes above the camera,
    grown by a `seam` pixels wide window), as a tall or wide cabinet's front does before the
    wall it stands against."""
    behind, fronts = jumps
    # cut at the far side of jumps, so that an object's face does not join the band's
    # background through its silhouette
    count, labels = cv2.connectedComponents((band & ~behind).view(np.uint8),
                                            connectivity=8, ltype=cv2.CV_32S)
    # occluded: next to a pixel of the band behind a jump (the part the jump cut off)
    in_front, occluded, at_border, stats = _part_flags(labels, count, z, behind, fronts,
                                                       band, border)
    area, top, bottom, left, right, sum_z = stats.T
    mean_z = sum_z / np.maximum(area, 1)
    extent = mean_z * np.maximum((right - left) / fx, (bottom - top) / fy)
    large = extent >= min_extent
    structure = (occluded & ~in_front) | large
    candidates = np.flatnonzero(large & in_front & ~at_border)
    if candidates.size:
        # the seam between a wall and the ceiling is a pixel or two wide
        near_ceiling = cv2.dilate(ceiling.view(np.uint8),
                                  np.ones((seam, seam), np.uint8)).view(bool)
    for c in candidates:
        # the part's rows and the few above it, where the step over its top is looked for
        rows = slice(max(int(top[c]) - reach, 0), int(bottom[c]))
        part = labels[rows] == c
        structure[c] = near_ceiling[rows][part].any() or not stands_in_front(
            part, z[rows], jump, jump_per_m, reach)
    structure |= at_border
    structure[0] = False
    if area[structure].sum() < enough:
        return False
    _mark(labels, structure, out)
    return True


# ---------------------------------------------------------------------------------------------
# compiled kernels (numba, cached on disk; `segment._compile_kernels` compiles every one of them)


@numba.njit(cache=True)
def _ransac_round(pts: np.ndarray, tol: np.ndarray, n: int, tri: np.ndarray,
                  scored: np.ndarray):  # pragma: no cover
    """One RANSAC search among the first n points of pts ((m, 3) metres) and their tolerances
    tol ((m,) metres): the planes through the point triples `tri` ((it, 3) indices) are scored
    by their inliers among the points `scored` ((s,) indices); the best (the first of the most
    inliers) is refined by least squares on all its inliers. Returns (unit normal (3,),
    offset, number of inliers of the refined plane, True) and moves the points it does not
    hold, in their order, to the front of pts and tol; or (zeros, 0, 0, False) when every
    triple was degenerate."""
    it = tri.shape[0]
    normals = np.zeros((it, 3))
    offsets = np.zeros(it)
    ok = np.zeros(it, dtype=np.bool_)
    for j in range(it):
        a, b, c = tri[j, 0], tri[j, 1], tri[j, 2]
        u0, u1, u2 = pts[b, 0] - pts[a, 0], pts[b, 1] - pts[a, 1], pts[b, 2] - pts[a, 2]
        v0, v1, v2 = pts[c, 0] - pts[a, 0], pts[c, 1] - pts[a, 1], pts[c, 2] - pts[a, 2]
        n0, n1, n2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
        norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if norm > 1e-9:
            ok[j] = True
            normals[j, 0], normals[j, 1], normals[j, 2] = n0 / norm, n1 / norm, n2 / norm
            offsets[j] = -(normals[j, 0] * pts[a, 0] + normals[j, 1] * pts[a, 1]
                           + normals[j, 2] * pts[a, 2])
    inliers = np.zeros(n, dtype=np.bool_)
    if not ok.any():
        return np.zeros(3), 0.0, 0, False
    m = scored.size
    x, y, z, t = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    for i in range(m):
        k = scored[i]
        x[i], y[i], z[i], t[i] = pts[k, 0], pts[k, 1], pts[k, 2], tol[k]
    best, best_count = -1, -1
    for j in range(it):
        if not ok[j]:
            continue
        a, b, c, d = normals[j, 0], normals[j, 1], normals[j, 2], offsets[j]
        count = 0
        for i in range(m):
            count += abs(x[i] * a + y[i] * b + z[i] * c + d) <= t[i]
        if count > best_count:
            best, best_count = j, count
    a, b, c, d = normals[best, 0], normals[best, 1], normals[best, 2], offsets[best]
    n_in = 0
    c0 = c1 = c2 = 0.0
    for i in range(n):
        if abs(pts[i, 0] * a + pts[i, 1] * b + pts[i, 2] * c + d) <= tol[i]:
            inliers[i] = True
            c0, c1, c2 = c0 + pts[i, 0], c1 + pts[i, 1], c2 + pts[i, 2]
            n_in += 1
    c0, c1, c2 = c0 / n_in, c1 / n_in, c2 / n_in
    scatter = np.zeros((3, 3))
    for i in range(n):
        if inliers[i]:
            e0, e1, e2 = pts[i, 0] - c0, pts[i, 1] - c1, pts[i, 2] - c2
            scatter[0, 0] += e0 * e0
            scatter[0, 1] += e0 * e1
            scatter[0, 2] += e0 * e2
            scatter[1, 1] += e1 * e1
            scatter[1, 2] += e1 * e2
            scatter[2, 2] += e2 * e2
    scatter[1, 0], scatter[2, 0], scatter[2, 1] = scatter[0, 1], scatter[0, 2], scatter[1, 2]
    # the normal is the direction of least spread: the smallest eigenvector of the scatter
    normal = np.linalg.eigh(scatter)[1][:, 0].copy()
    offset = -(normal[0] * c0 + normal[1] * c1 + normal[2] * c2)
    k = 0
    for i in range(n):
        if abs(pts[i, 0] * normal[0] + pts[i, 1] * normal[1] + pts[i, 2] * normal[2]
               + offset) > tol[i]:  # not held: kept for the next search
            pts[k, 0], pts[k, 1], pts[k, 2], tol[k] = pts[i, 0], pts[i, 1], pts[i, 2], tol[i]
            k += 1
    return normal, offset, n - k, True


@numba.njit(cache=True)
def _plane_band(z: np.ndarray, x_over_z: np.ndarray, y_over_z: np.ndarray,
                valid: np.ndarray, taken: np.ndarray, normal: np.ndarray, offset: np.float32,
                distance: np.float32, per_m2: np.float32,
                band: np.ndarray) -> int:  # pragma: no cover
    """Writes into `band` ((h, w) bool) the pixels of `valid` and not `taken` ((h, w) bool)
    whose point (depth z (h, w) float32 metres along the rays x_over_z, y_over_z) lies within
    distance + per_m2 z^2 of the plane normal . p + offset = 0 (normal (3,) float32); returns
    their number."""
    n0, n1, n2 = normal[0], normal[1], normal[2]
    count = 0
    for r in range(z.shape[0]):
        for c in range(z.shape[1]):
            d = z[r, c]
            # the distance from the plane is z (normal . ray) + offset
            on = valid[r, c] and not taken[r, c] and (
                abs(d * (x_over_z[r, c] * n0 + y_over_z[r, c] * n1 + n2) + offset)
                <= distance + per_m2 * d * d)
            band[r, c] = on
            count += on
    return count


@numba.njit(cache=True, fastmath=_FAST)
def _restore_slices(level: np.ndarray, out: np.ndarray, behind: np.ndarray, z: np.ndarray,
                    x_over_z: np.ndarray, y_over_z: np.ndarray, up: np.ndarray, k: int,
                    jump: np.float32, jump_per_m: np.float32,
                    along_columns: bool) -> int:  # pragma: no cover
    """Takes the slices of level bands through objects out of `out` ((h, w) bool, the room
    structure) and returns how many pixels it took out.

    A slice is a run of at most k pixels of `level` ((h, w) bool, the removed level planes'
    bands, all in `out`) along an image column (along a row if not `along_columns`), none of
    them in `behind` ((h, w) bool, the far side of depth jumps), such that the pixels just
    before and after it are kept (with depth, neither in `out` nor in `behind`), their depths
    (z (h, w) float32 metres, 0 = none) differ by at most jump + jump_per_m * depth, and
    their points (along the rays x_over_z, y_over_z, (h, w) float32) are no farther apart
    horizontally along the line of sight than along `up` ((3,) float32 unit vector, the up
    direction in the optical frame): they lie on a surface that rises, seen from the camera,
    steeper than 45 deg."""
    h, w = z.shape
    # The image is read row by row (as it lies in memory), each line (column, or row) with
    # its open run: where it began (-1: none) and whether a pixel of it is behind a jump.
    start = np.full(max(h, w), -1, dtype=np.int64)
    cut = np.zeros(max(h, w), dtype=np.bool_)
    taken = 0
    u0, u1, u2 = up[0], up[1], up[2]
    for r in range(h):
        for c in range(w):
            line, pos = (c, r) if along_columns else (r, c)
            if level[r, c]:
                if start[line] < 0:
                    start[line], cut[line] = pos, behind[r, c]
                else:
                    cut[line] |= behind[r, c]
                continue
            first = start[line]
            if first < 0:
                continue
            start[line] = -1  # the run [first, pos) ends here, at (r, c)
            if cut[line] or pos - first > k or first == 0:
                continue
            ra, ca = (first - 1, c) if along_columns else (r, first - 1)
            za, zb = z[ra, ca], z[r, c]
            if not ((za > 0) & (zb > 0) & ~out[ra, ca] & ~out[r, c] & ~behind[ra, ca]
                    & ~behind[r, c]):
                continue
            # one surface across the run, not two things at different depths
            if abs(za - zb) > jump + jump_per_m * min(za, zb):
                continue
            # An object's side rises through the band; the plane itself lies across it. A
            # table top seen nearly edge-on between an object on it and the table's front
            # is a few pixels tall and continuous in depth too, but its ends are at one
            # height, the table's depth apart along the line of sight; so is the floor
            # between the specks of it that depth noise leaves outside the band. Only the
            # horizontal part along the line of sight counts: a run across the image's up
            # direction (a rolled camera) also moves sideways along an upright surface.
            xa, ya = x_over_z[ra, ca], y_over_z[ra, ca]
            d0, d1, d2 = za * xa - zb * x_over_z[r, c], za * ya - zb * y_over_z[r, c], za - zb
            rise = d0 * u0 + d1 * u1 + d2 * u2
            # the line of sight to the first end, without its part along up
            along = xa * u0 + ya * u1 + u2
            s0, s1, s2 = xa - along * u0, ya - along * u1, 1.0 - along * u2
            sight = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            if abs(d0 * s0 + d1 * s1 + d2 * s2) > abs(rise) * sight:
                continue
            for j in range(first, pos):
                if along_columns:
                    out[j, c] = False
                else:
                    out[r, j] = False
            taken += pos - first
        if not along_columns:
            start[r] = -1  # a run reaching the row's end has no kept pixel after it
    return taken


@numba.njit(cache=True)
def _part_flags(labels: np.ndarray, count: int, z: np.ndarray, behind: np.ndarray,
                fronts: np.ndarray, band: np.ndarray, border: np.ndarray
                ):  # pragma: no cover
    """For each of the `count` labels of `labels` ((h, w) int32, 0 = none): whether it holds a
    pixel of `fronts`, whether it is the largest label next to (3 x 3) a pixel of
    `behind & band`, whether it holds a pixel of `border` (all (h, w) bool), and (count, 6)
    float64 its pixel count, bounding box (top, bottom, left, right, ends exclusive) and sum
    of depths `z`."""
    h, w = labels.shape
    in_front = np.zeros(count, dtype=np.bool_)
    occluded = np.zeros(count, dtype=np.bool_)
    at_border = np.zeros(count, dtype=np.bool_)
    stats = np.zeros((count, 6))
    stats[:, 1], stats[:, 3] = h, w
    for r in range(h):
        for c in range(w):
            if behind[r, c] and band[r, c]:
                top = 0
                for rr in range(max(r - 1, 0), min(r + 2, h)):
                    for cc in range(max(c - 1, 0), min(c + 2, w)):
                        top = max(top, labels[rr, cc])
                occluded[top] = True
            lab = labels[r, c]
            if lab == 0:
                continue
            if fronts[r, c]:
                in_front[lab] = True
            if border[r, c]:
                at_border[lab] = True
            stats[lab, 0] += 1
            stats[lab, 1] = min(stats[lab, 1], r)
            stats[lab, 2] = max(stats[lab, 2], r + 1)
            stats[lab, 3] = min(stats[lab, 3], c)
            stats[lab, 4] = max(stats[lab, 4], c + 1)
            stats[lab, 5] += z[r, c]
    return in_front, occluded, at_border, stats


@numba.njit(cache=True)
def _mark(labels: np.ndarray, chosen: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """Sets `out` ((h, w) bool) where `chosen` ((count,) bool) holds for the pixel's label
    (`labels` (h, w) int32)."""
    for r in range(labels.shape[0]):
        for c in range(labels.shape[1]):
            if chosen[labels[r, c]]:
                out[r, c] = True
