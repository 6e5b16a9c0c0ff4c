"""Tests for tcaff_gtsam.object_map.ObjectMap: validation, filtering, ages and file round trips."""

from __future__ import annotations

import math
import os
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.object_map import ObjectMap

FIELDS = ("centroids", "widths", "heights", "last_seen")


def make_map(n: int = 4, seed: int = 0) -> ObjectMap:
    rng = np.random.default_rng(seed)
    return ObjectMap(
        centroids=rng.uniform(-10, 10, (n, 3)),
        widths=rng.uniform(0.1, 3.0, n),
        heights=rng.uniform(0.1, 3.0, n),
        last_seen=rng.uniform(0.0, 100.0, n),
    )


def valid_kwargs(n: int = 3) -> dict:
    return {
        "centroids": np.arange(3.0 * n).reshape(n, 3),
        "widths": np.full(n, 0.5),
        "heights": np.full(n, 1.5),
        "last_seen": np.arange(float(n)),
    }


def field_error(name: str) -> str:
    """Regex that matches an error message naming `name` as the offending field."""
    return re.escape(f"ObjectMap.{name}") + r"\b"


def assert_maps_equal(a: ObjectMap, b: ObjectMap) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float64
        assert x.shape == y.shape
        np.testing.assert_array_equal(x, y)


# ---------------------------------------------------------------------------------------------
# construction


def test_valid_construction_copies_and_converts():
    kwargs = {
        "centroids": [[1, 2, 3], [4, 5, 6]],
        "widths": [1, 2],
        "heights": (0.5, 0.25),
        "last_seen": np.array([10, 20], dtype=np.int32),
    }
    m = ObjectMap(**kwargs)
    assert len(m) == 2
    assert m.centroids.shape == (2, 3)
    for name in FIELDS:
        arr = getattr(m, name)
        assert isinstance(arr, np.ndarray)
        assert arr.dtype == np.float64
    np.testing.assert_array_equal(m.centroids, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(m.heights, [0.5, 0.25])
    np.testing.assert_array_equal(m.last_seen, [10, 20])


def test_arrays_are_read_only_copies():
    source = valid_kwargs(3)
    m = ObjectMap(**source)
    for name in FIELDS:
        arr = getattr(m, name)
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[0] = 99.0
    # Mutating the caller's arrays afterwards does not change the map.
    source["centroids"][0, 0] = 1234.0
    source["widths"][0] = 1234.0
    assert m.centroids[0, 0] == 0.0
    assert m.widths[0] == 0.5


def test_fields_cannot_be_reassigned():
    m = make_map()
    with pytest.raises(AttributeError):
        m.widths = np.zeros(4)


def test_zero_sizes_are_legal():
    kwargs = valid_kwargs(2)
    kwargs["widths"] = [0.0, 0.0]
    kwargs["heights"] = [0.0, 1.0]
    m = ObjectMap(**kwargs)
    np.testing.assert_array_equal(m.widths, [0.0, 0.0])


@pytest.mark.parametrize(
    "m",
    [
        ObjectMap.empty(),
        ObjectMap([], [], [], []),
        ObjectMap(np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0)),
    ],
    ids=["empty()", "lists", "arrays"],
)
def test_empty_maps_are_legal(m):
    assert len(m) == 0
    assert m.centroids.shape == (0, 3)
    for name in ("widths", "heights", "last_seen"):
        assert getattr(m, name).shape == (0,)
    assert len(m.recent(10.0, 5.0)) == 0
    assert m.ages(10.0).shape == (0,)
    assert repr(m) == "ObjectMap(n=0)"


@pytest.mark.parametrize(
    ("field", "row", "value"),
    [
        ("centroids", (1, 2), np.nan),
        ("centroids", (0, 0), np.inf),
        ("widths", 1, np.nan),
        ("heights", 0, -np.inf),
        ("last_seen", 2, np.inf),
        ("last_seen", 0, np.nan),
    ],
)
def test_non_finite_values_rejected_naming_the_field(field, row, value):
    kwargs = valid_kwargs(3)
    kwargs[field][row] = value
    with pytest.raises(DataError, match=field_error(field)) as info:
        ObjectMap(**kwargs)
    assert "non-finite" in str(info.value)


@pytest.mark.parametrize("field", ["widths", "heights", "last_seen"])
@pytest.mark.parametrize("n_bad", [0, 2, 4])
def test_mismatched_lengths_rejected_naming_the_field(field, n_bad):
    kwargs = valid_kwargs(3)
    kwargs[field] = np.ones(n_bad)
    with pytest.raises(DataError, match=field_error(field)):
        ObjectMap(**kwargs)


@pytest.mark.parametrize("field", ["widths", "heights", "last_seen"])
def test_two_dimensional_per_object_field_rejected(field):
    kwargs = valid_kwargs(3)
    kwargs[field] = np.ones((3, 1))
    with pytest.raises(DataError, match=field_error(field)):
        ObjectMap(**kwargs)


@pytest.mark.parametrize(
    "centroids", [np.zeros((3, 2)), np.zeros((3, 4)), np.zeros(9), np.zeros((3, 3, 1))]
)
def test_centroids_of_wrong_shape_rejected(centroids):
    kwargs = valid_kwargs(3)
    kwargs["centroids"] = centroids
    with pytest.raises(DataError, match=field_error("centroids")):
        ObjectMap(**kwargs)


@pytest.mark.parametrize("field", ["widths", "heights"])
def test_negative_sizes_rejected_naming_the_field(field):
    kwargs = valid_kwargs(3)
    kwargs[field][2] = -0.01
    with pytest.raises(DataError, match=field_error(field)) as info:
        ObjectMap(**kwargs)
    assert "index 2" in str(info.value)


def test_negative_last_seen_is_allowed():
    kwargs = valid_kwargs(2)
    kwargs["last_seen"] = [-5.0, -1.0]
    assert len(ObjectMap(**kwargs)) == 2


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("centroids", [["a", "b", "c"]]),
        ("centroids", [[1.0, 2.0, object()]]),
        ("widths", ["wide"]),
        ("heights", [{"h": 1}]),
        ("last_seen", ["yesterday"]),
    ],
)
def test_non_numeric_input_rejected_naming_the_field(field, value):
    kwargs = valid_kwargs(1)
    kwargs[field] = value
    with pytest.raises(DataError, match=field_error(field)):
        ObjectMap(**kwargs)


# ---------------------------------------------------------------------------------------------
# recent / ages / subset


def test_recent_hand_made():
    m = ObjectMap(
        centroids=np.arange(15.0).reshape(5, 3),
        widths=[1.0, 2.0, 3.0, 4.0, 5.0],
        heights=[0.1, 0.2, 0.3, 0.4, 0.5],
        last_seen=[0.0, 5.0, 9.0, 10.0, 12.0],
    )
    r = m.recent(now=10.0, kappa=5.0)  # ages 10, 5, 1, 0, -2; 5 is not < 5
    assert len(r) == 3
    np.testing.assert_array_equal(r.last_seen, [9.0, 10.0, 12.0])
    np.testing.assert_array_equal(r.widths, [3.0, 4.0, 5.0])
    np.testing.assert_array_equal(r.heights, [0.3, 0.4, 0.5])
    np.testing.assert_array_equal(r.centroids, m.centroids[2:])
    # an infinite kappa (FrameAlignerParams allows it: no limit) keeps every object
    assert len(m.recent(now=10.0, kappa=np.inf)) == 5
    assert len(m.recent(now=10.0, kappa=5.5)) == 4
    assert len(m.recent(now=100.0, kappa=1.0)) == 0


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=0, max_size=30),
    st.floats(-1e3, 1e3, allow_nan=False),
    st.floats(1e-3, 1e3, allow_nan=False),
)
def test_recent_keeps_exactly_the_recent_objects(stamps, now, kappa):
    n = len(stamps)
    m = ObjectMap(
        centroids=np.arange(3.0 * n).reshape(n, 3),
        widths=np.arange(float(n)),
        heights=np.arange(float(n)) + 0.5,
        last_seen=stamps,
    )
    r = m.recent(now, kappa)
    keep = [i for i, s in enumerate(stamps) if now - s < kappa]
    assert len(r) == len(keep)
    np.testing.assert_array_equal(r.widths, np.array(keep, dtype=float))
    np.testing.assert_array_equal(r.last_seen, np.array([stamps[i] for i in keep], float))
    np.testing.assert_array_equal(r.centroids, m.centroids[keep].reshape(-1, 3))
    assert all(now - s < kappa for s in r.last_seen)


@pytest.mark.parametrize(("now", "kappa"), [(1.0, 0.0), (1.0, -1.0), (np.nan, 1.0),
                                            (1.0, np.nan), (1.0, -np.inf), (np.inf, 1.0)])
def test_recent_rejects_bad_arguments(now, kappa):
    with pytest.raises(DataError, match=r"^ObjectMap\.recent_indices: "):
        make_map().recent(now, kappa)
    with pytest.raises(DataError, match=r"^ObjectMap\.recent_indices: "):
        make_map().recent_indices(now, kappa)


def test_ages_clip_future_stamps_to_zero():
    m = ObjectMap(np.zeros((4, 3)), np.ones(4), np.ones(4), [1.0, 7.5, 10.0, 12.0])
    ages = m.ages(10.0)
    np.testing.assert_array_equal(ages, [9.0, 2.5, 0.0, 0.0])
    assert ages.shape == (4,)
    assert np.all(ages >= 0)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3, allow_nan=False), max_size=20),
       st.floats(-1e3, 1e3, allow_nan=False))
def test_ages_property(stamps, now):
    n = len(stamps)
    m = ObjectMap(np.zeros((n, 3)), np.ones(n), np.ones(n), stamps)
    np.testing.assert_array_equal(m.ages(now), [max(now - s, 0.0) for s in stamps])


def test_subset_with_mask_and_index():
    m = make_map(5, seed=3)
    mask = np.array([True, False, True, False, True])
    s = m.subset(mask)
    assert len(s) == 3
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(s, name), getattr(m, name)[[0, 2, 4]])
        assert not getattr(s, name).flags.writeable
    idx = np.array([4, 1])
    s = m.subset(idx)
    assert len(s) == 2
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(s, name), getattr(m, name)[[4, 1]])
        assert not getattr(s, name).flags.writeable
        assert not np.shares_memory(getattr(s, name), getattr(m, name))
    for empty in (m.subset(np.zeros(5, dtype=bool)), m.subset(np.array([], dtype=int))):
        assert len(empty) == 0 and empty.centroids.shape == (0, 3)


# ---------------------------------------------------------------------------------------------
# save / load


@pytest.mark.parametrize("n", [0, 1, 7])
def test_save_load_round_trip_exact(tmp_path, n):
    m = make_map(n, seed=n) if n else ObjectMap.empty()
    path = tmp_path / "map.npz"
    m.save(path)
    assert path.is_file()
    loaded = ObjectMap.load(path)
    assert isinstance(loaded, ObjectMap)
    assert len(loaded) == n
    assert_maps_equal(loaded, m)
    for name in FIELDS:
        assert not getattr(loaded, name).flags.writeable


def test_save_load_accepts_str_paths(tmp_path):
    m = make_map(3)
    path = str(tmp_path / "map.npz")
    m.save(path)
    assert_maps_equal(ObjectMap.load(path), m)


def test_save_load_round_trip_without_npz_suffix(tmp_path):
    m = make_map(3)
    path = tmp_path / "map.bin"
    m.save(path)
    assert_maps_equal(ObjectMap.load(path), m)


def test_load_missing_file(tmp_path):
    with pytest.raises(DataError, match="no such map file"):
        ObjectMap.load(tmp_path / "does_not_exist.npz")


def test_load_npz_without_the_right_arrays(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, centroids=np.zeros((1, 3)), widths=np.ones(1))
    with pytest.raises(DataError, match="not an ObjectMap file") as info:
        ObjectMap.load(path)
    assert "heights" in str(info.value) and "last_seen" in str(info.value)


def test_load_npz_with_invalid_contents(tmp_path):
    path = tmp_path / "bad.npz"
    np.savez(path, centroids=np.zeros((2, 3)), widths=[1.0, -1.0], heights=[1.0, 1.0],
             last_seen=[0.0, 0.0])
    with pytest.raises(DataError, match=field_error("widths")):
        ObjectMap.load(path)


def test_load_npz_with_object_arrays_refuses_pickle(tmp_path):
    path = tmp_path / "pickled.npz"
    np.savez(path, centroids=np.array([None, None, None], dtype=object), widths=[1.0],
             heights=[1.0], last_seen=[0.0])
    with pytest.raises(DataError):
        ObjectMap.load(path)


def _write_text_garbage(path):
    path.write_bytes(b"this is definitely not a numpy file\n" * 10)


def _write_binary_garbage(path):
    path.write_bytes(bytes(range(256)) * 4)


def _write_empty(path):
    path.write_bytes(b"")


def _write_truncated_npz(path):
    make_map(5).save(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _write_npy(path):
    with open(path, "wb") as fh:
        np.save(fh, np.zeros((3, 3)))


@pytest.mark.parametrize(
    "writer",
    [
        _write_text_garbage,
        _write_binary_garbage,
        _write_empty,
        _write_truncated_npz,
        _write_npy,
    ],
    ids=["text", "binary", "empty", "truncated-npz", "npy"],
)
def test_load_garbage_file(tmp_path, writer):
    path = tmp_path / "garbage.npz"
    writer(path)
    with pytest.raises(DataError):
        ObjectMap.load(path)


def test_load_directory(tmp_path):
    with pytest.raises(DataError):
        ObjectMap.load(tmp_path)


# ---------------------------------------------------------------------------------------------
# bad input: DataError naming the argument, never another exception

#: values that are not a finite time: strings, None, arrays, NaN and infinities, complex
#: numbers, booleans, containers, ints beyond the floats
junk_times = st.one_of(
    st.text(max_size=5), st.none(), st.booleans(), st.binary(max_size=4),
    st.sampled_from([math.nan, math.inf, -math.inf, np.float64("nan"), np.float32("inf"),
                     10**400, -(10**400), 1 + 2j, np.complex128(1.0), np.array(1.0),
                     np.ones(3), np.ones((2, 2)), [1.0], (1.0,), {"t": 1.0}, object()]),
    st.lists(st.floats(), max_size=3),
    st.complex_numbers(max_magnitude=1e3),
)


@settings(max_examples=60, deadline=None)
@given(junk_times)
def test_any_junk_now_is_a_data_error_naming_now(now):
    m = make_map()
    for call in (lambda: m.ages(now), lambda: m.recent(now, 5.0),
                 lambda: m.recent_indices(now, 5.0)):
        with pytest.raises(DataError, match=r"^ObjectMap\.(ages|recent_indices): now must be "
                                            r"a finite number of seconds, got "):
            call()


@settings(max_examples=40, deadline=None)
@given(st.one_of(st.integers(-10**6, 10**6), st.floats(-1e9, 1e9),
                 st.sampled_from([np.float32(3.5), np.int64(7), np.uint8(3)])))
def test_any_finite_number_is_a_time(now):
    m = make_map()
    np.testing.assert_array_equal(m.ages(now), np.maximum(float(now) - m.last_seen, 0.0))


def test_ages_at_nan_is_an_error_not_nans():
    with pytest.raises(DataError, match=r"^ObjectMap\.ages: now must be a finite number of "
                                        r"seconds, got nan \(not finite\)"):
        make_map().ages(float("nan"))


@pytest.mark.parametrize("kappa", ["5", None, 1j, np.ones(2), True])
def test_recent_rejects_kappa_that_is_no_number(kappa):
    with pytest.raises(DataError, match=r"^ObjectMap\.recent_indices: kappa must be a number"):
        make_map().recent(1.0, kappa)


@pytest.mark.parametrize(("index", "message"), [
    ([999], "index 999 is out of range for a map of 4 objects"),
    (np.array([0, -5]), "index -5 is out of range"),
    (np.array([True, False]), "a boolean mask of length 2, the map has 4 objects"),
    (np.array([0.0, 1.0]), "must be a boolean mask"),
    (1, "must be a boolean mask"),
    ("0", "must be a boolean mask"),
    (None, "must be a boolean mask"),
    (np.zeros((2, 2), int), "must be a boolean mask"),
    (slice(0, 2), "must be a boolean mask"),
])
def test_subset_refuses_bad_indices(index, message):
    with pytest.raises(DataError, match=rf"^ObjectMap\.subset: .*{re.escape(message)}"):
        make_map(4).subset(index)


def test_subset_still_takes_negative_and_empty_indices():
    m = make_map(4)
    np.testing.assert_array_equal(m.subset([-1]).centroids, m.centroids[[3]])
    assert len(m.subset([])) == 0


@pytest.mark.parametrize("field", FIELDS)
@pytest.mark.parametrize("value", [1 + 1j, np.complex64(2.0)])
def test_complex_values_are_refused_not_cast(field, value):
    """numpy would drop the imaginary part with a warning and keep going."""
    kwargs = valid_kwargs(2)
    kwargs[field] = np.asarray(kwargs[field]) * value
    with pytest.raises(DataError, match=field_error(field) + " must be real numbers"):
        ObjectMap(**kwargs)


@settings(max_examples=30, deadline=None)
@given(field=st.sampled_from([*FIELDS, "descriptors"]),
       dtype=st.sampled_from(["bool", "complex128", "datetime64[s]", "timedelta64[ms]", "V8"]),
       n=st.integers(0, 4))
def test_a_map_file_with_an_array_of_another_dtype_names_the_file_array_and_dtype(
        tmp_path_factory, field, dtype, n):
    """numpy casts booleans to 0 and 1 without a word (a map of boolean centroids was
    aligned), and drops an imaginary part with a warning."""
    path = tmp_path_factory.mktemp("dtype") / "map.npz"
    arrays = {**valid_kwargs(n), "descriptors": np.ones((n, 1))}
    arrays[field] = np.zeros(np.shape(arrays[field]), dtype)
    np.savez(path, **arrays)
    with pytest.raises(DataError) as info:
        ObjectMap.load(path)
    assert str(info.value) == (f"{path}: array {field!r} has dtype {np.dtype(dtype)}, not "
                               f"real numbers")


def test_a_map_file_with_invalid_contents_names_the_file(tmp_path):
    path = tmp_path / "flat.npz"
    np.savez(path, **{**valid_kwargs(2), "centroids": np.zeros((2, 2))})
    with pytest.raises(DataError, match=f"^{re.escape(str(path))}: " + field_error("centroids")
                       + re.escape(" must have shape (k, 3), got (2, 2)")):
        ObjectMap.load(path)


def _npy_bytes(shape, payload: bytes) -> bytes:
    """An .npy member whose header declares `shape` of float64, followed by `payload`."""
    import io

    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buffer, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return buffer.getvalue() + payload


@pytest.mark.parametrize("shape", [(10**11, 3), (2**40,), (3, 10**12)])
def test_a_header_declaring_a_huge_array_is_refused_before_reading(tmp_path, shape):
    """numpy allocates the declared shape before reading: MemoryError for (1e11, 3)."""
    import zipfile

    path = tmp_path / "huge.npz"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("centroids.npy", _npy_bytes(shape, bytes(48)))
        for name in ("widths", "heights", "last_seen"):
            archive.writestr(f"{name}.npy", _npy_bytes((2,), bytes(16)))
    with pytest.raises(DataError, match=r"corrupt map archive, array 'centroids' declares "
                                        r"shape .* but holds 48 bytes"):
        ObjectMap.load(path)


def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "map.npz"
    os.mkfifo(fifo)
    with pytest.raises(DataError, match="not a regular file"):
        ObjectMap.load(fifo)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_any_damaged_map_file_loads_or_is_a_data_error(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("flip") / "map.npz"
    make_map(5).save(path)
    raw = bytearray(path.read_bytes())
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] ^= 1 << data.draw(st.integers(0, 7))
    raw = raw[: data.draw(st.integers(0, len(raw)))]
    path.write_bytes(bytes(raw))
    try:
        loaded = ObjectMap.load(path)
    except DataError:
        return
    assert isinstance(loaded, ObjectMap)


# ---------------------------------------------------------------------------------------------
# descriptors: (n, d) non-negative rows of unit length, kept through subsets and files


def unit_rows(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    rows = rng.random((n, d)) * (rng.random((n, d)) < 0.7)
    rows[:, 0] += 0.05  # never all zero
    return rows / np.linalg.norm(rows, axis=1, keepdims=True)


def described_map(n: int = 5, d: int = 7, seed: int = 0) -> ObjectMap:
    m = make_map(n, seed)
    return ObjectMap(m.centroids, m.widths, m.heights, m.last_seen,
                     unit_rows(np.random.default_rng(seed), n, d))


def test_descriptors_are_validated_copied_and_read_only():
    rows = unit_rows(np.random.default_rng(1), 3, 4)
    given_rows = rows.copy()
    m = ObjectMap(**valid_kwargs(3), descriptors=rows.tolist())
    assert m.descriptors.dtype == np.float64 and m.descriptors.shape == (3, 4)
    np.testing.assert_allclose(m.descriptors, rows, rtol=0, atol=0)
    assert not m.descriptors.flags.writeable
    m2 = ObjectMap(**valid_kwargs(3), descriptors=rows)
    rows[0, 0] = 99.0
    assert m2.descriptors[0, 0] != 99.0 and not np.shares_memory(m2.descriptors, rows)
    np.testing.assert_array_equal(m2.descriptors, given_rows)
    with pytest.raises(ValueError):
        m.descriptors[0, 0] = 0.5
    assert ObjectMap(**valid_kwargs(3)).descriptors is None
    assert ObjectMap.empty().descriptors is None
    # one-hot rows and a float32-rounded row are unit enough
    ObjectMap(**valid_kwargs(2), descriptors=np.eye(2, 5))
    ObjectMap(**valid_kwargs(3), descriptors=given_rows.astype(np.float32))


@pytest.mark.parametrize("shape", [(0, 1), (0, 6)])
def test_an_empty_map_takes_empty_descriptors(shape):
    m = ObjectMap(**valid_kwargs(0), descriptors=np.zeros(shape))
    assert len(m) == 0 and m.descriptors.shape == shape


def _row_one(value) -> np.ndarray:
    rows = np.eye(3, 4)
    rows[1] = value
    return rows


@pytest.mark.parametrize(("descriptors", "message"), [
    (np.eye(3, 4)[0], "must have shape (3, d) with d >= 1, got (4,)"),
    (np.eye(2, 4), "must have shape (3, d) with d >= 1, got (2, 4)"),
    (np.eye(4, 4), "must have shape (3, d) with d >= 1, got (4, 4)"),
    (np.zeros((3, 0)), "must have shape (3, d) with d >= 1, got (3, 0)"),
    (np.ones((3, 4, 1)) / 2, "must have shape (3, d) with d >= 1, got (3, 4, 1)"),
    (_row_one([0.6, -0.8, 0.0, 0.0]), "must be finite numbers >= 0, got -0.8 at row 1, column 1"),
    (_row_one([np.nan, 1.0, 0.0, 0.0]), "must be finite numbers >= 0, got nan at row 1, column 0"),
    (_row_one([0.0, 0.0, np.inf, 0.0]), "must be finite numbers >= 0, got inf at row 1, column 2"),
    (_row_one([0.6, 0.6, 0.6, 0.6]), "rows must have unit length (L2), row 1 has length 1.2"),
    (_row_one([0.0, 0.0, 0.0, 0.0]), "rows must have unit length (L2), row 1 has length 0"),
    (_row_one([0.5, 0.5, 0.0, 0.0]), "rows must have unit length (L2), row 1 has length 0.707107"),
    (np.full((3, 4), "x"), "must be real numbers"),
    (np.eye(3, 4) * (1 + 1j), "must be real numbers"),
])
def test_bad_descriptors_are_refused_naming_the_row_and_value(descriptors, message):
    with pytest.raises(DataError, match=r"^ObjectMap\.descriptors " + re.escape(message)):
        ObjectMap(**valid_kwargs(3), descriptors=descriptors)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 6), st.integers(1, 9), st.data())
def test_unit_length_is_checked_to_1e_4_on_every_row(seed, n, d, data):
    rng = np.random.default_rng(seed)
    rows = unit_rows(rng, n, d)
    row = data.draw(st.integers(0, n - 1))
    ok = rows.copy()
    ok[row] *= 1 + data.draw(st.floats(-5e-5, 5e-5))
    np.testing.assert_array_equal(ObjectMap(**valid_kwargs(n), descriptors=ok).descriptors, ok)
    bad = rows.copy()
    scale = 1 + data.draw(st.sampled_from([-1, 1])) * data.draw(st.floats(3e-4, 0.5))
    bad[row] *= scale
    with pytest.raises(DataError, match=rf"row {row} has length ") as info:
        ObjectMap(**valid_kwargs(n), descriptors=bad)
    length = float(str(info.value).rsplit(" ", 1)[1])
    assert length == pytest.approx(scale, rel=1e-5)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 8), st.data())
def test_subset_and_recent_keep_the_descriptors_of_their_rows(seed, n, data):
    m = described_map(n, seed=seed % 1000)
    mask = np.array(data.draw(st.lists(st.booleans(), min_size=n, max_size=n)))
    for index in (mask, np.flatnonzero(mask)[::-1]):
        s = m.subset(index)
        np.testing.assert_array_equal(s.descriptors, m.descriptors[index])
        np.testing.assert_array_equal(s.centroids, m.centroids[index])
        assert s.descriptors.shape == (len(s), 7)
        assert not s.descriptors.flags.writeable
        assert not np.shares_memory(s.descriptors, m.descriptors)
    now = data.draw(st.floats(0.0, 100.0))
    kappa = data.draw(st.floats(0.5, 100.0))
    kept = np.flatnonzero(now - m.last_seen < kappa)
    recent = m.recent(now, kappa)
    np.testing.assert_array_equal(recent.descriptors, m.descriptors[kept])
    np.testing.assert_array_equal(recent.last_seen, m.last_seen[kept])
    assert make_map(n).subset(mask).descriptors is None


@pytest.mark.parametrize("n", [0, 1, 5])
def test_save_load_round_trips_descriptors(tmp_path, n):
    m = described_map(n, seed=n) if n else ObjectMap(**valid_kwargs(0),
                                                       descriptors=np.zeros((0, 7)))
    path = tmp_path / "described.npz"
    m.save(path)
    with np.load(path) as data:
        assert "descriptors" in data.files
    loaded = ObjectMap.load(path)
    assert_maps_equal(loaded, m)
    assert loaded.descriptors.shape == (n, 7) and loaded.descriptors.dtype == np.float64
    np.testing.assert_array_equal(loaded.descriptors, m.descriptors)
    assert not loaded.descriptors.flags.writeable


def test_save_load_without_descriptors_gives_none(tmp_path):
    path = tmp_path / "plain.npz"
    make_map(3).save(path)
    with np.load(path) as data:
        assert "descriptors" not in data.files
    assert ObjectMap.load(path).descriptors is None


def test_a_map_file_with_bad_descriptors_is_a_data_error_naming_them(tmp_path):
    m = make_map(2)
    path = tmp_path / "bad.npz"
    np.savez(path, centroids=m.centroids, widths=m.widths, heights=m.heights,
             last_seen=m.last_seen, descriptors=np.array([[1.0, 0.0], [0.9, 0.0]]))
    with pytest.raises(DataError, match=r"ObjectMap\.descriptors .*row 1 has length 0\.9"):
        ObjectMap.load(path)
