"""JPEG images cut short, in image files (`image_files.read_image`) and in Kimera-like bags
(`kimera_multi.RobotBags.frames`): refused, while whole JPEGs, with whatever follows their
end-of-image marker, decode as they were encoded.

The JPEGs come from OpenCV and from Pillow (baseline and progressive, with and without restart
markers), some with segments a walk must skip by their length: Exif (APP1), a JFXX thumbnail
(APP0, a whole JPEG with its own end-of-image marker) and a comment holding 0xFF 0xD9 before
the last scan (in a progressive JPEG, between two scans), where a file cut right after those
bytes ends as a whole JPEG does.
"""

from __future__ import annotations

import io
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from PIL import Image
from rosbags.rosbag1 import Writer
from tcaff_gtsam.eval.datasets.image_files import read_image
from tcaff_gtsam.eval.datasets.kimera_multi import RobotBags
from tcaff_gtsam.eval.sim import kimera_bags as kb

from tcaff_gtsam.errors import DataError

EOI = b"\xff\xd9"
#: a comment that holds the end-of-image marker's bytes
COMMENT = b"made by a camera \xff\xd9 and more"
#: bytes that cameras, phones and tools append after the end-of-image marker: an MPF image, a
#: maker note, padding that is not zeros
TAILS = [b"", bytes(16), b"\xff\xd8\xff\xe1\x00\x10maker data", b"\xff" * 7, b"\n",
         b"\xff\xd9\xff\xd9garbage"]


def segment(code: int, payload: bytes) -> bytes:
    return bytes([0xFF, code]) + (len(payload) + 2).to_bytes(2, "big") + payload


def scan_starts(jpeg: bytes) -> list[int]:
    """Where the encoder's SOS markers are. 0xFF 0xDA occurs nowhere else in these files:
    entropy-coded data has 0xFF only before 0x00 or a restart marker, Huffman symbols are at
    most 0xFA, and quality >= 50 keeps quantisation values below 0xFF."""
    starts, at = [], jpeg.find(b"\xff\xda")
    while at >= 0:
        starts.append(at)
        at = jpeg.find(b"\xff\xda", at + 2)
    return starts


def thumbnail() -> bytes:
    rng = np.random.default_rng(5)
    return cv2.imencode(".jpg", rng.integers(0, 256, (16, 16, 3), np.uint8))[1].tobytes()


@st.composite
def jpegs(draw, max_side: int = 40) -> tuple[bytes, bytes]:
    """(the encoder's JPEG, the same with the drawn extra segments): both decode alike."""
    h, w = draw(st.integers(8, max_side)), draw(st.integers(8, max_side))
    grey = draw(st.booleans())
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    smooth = np.linspace(0, 255, w)[None, :] * np.ones((h, 1))
    noise = rng.integers(0, 256, (h, w, 3))
    image = np.clip(np.where(rng.random((h, w, 1)) < 0.5, smooth[..., None], noise), 0, 255
                    ).astype(np.uint8)
    image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if grey else image
    quality, progressive = draw(st.integers(50, 95)), draw(st.booleans())
    restart = draw(st.sampled_from([0, 1, 3]))  # MCUs between restart markers (0: none)
    exif = Image.Exif() if draw(st.booleans()) else None
    if exif is not None:
        exif[0x010F] = "Maker"
    if draw(st.sampled_from(["opencv", "pillow"])) == "opencv":
        params = [cv2.IMWRITE_JPEG_QUALITY, quality, cv2.IMWRITE_JPEG_PROGRESSIVE,
                  int(progressive), cv2.IMWRITE_JPEG_RST_INTERVAL, restart]
        jpeg = cv2.imencode(".jpg", image, params)[1].tobytes()
        if exif is not None:  # an Exif APP1 (the maker only) after the JFIF APP0
            at = 4 + int.from_bytes(jpeg[4:6], "big")
            jpeg = jpeg[:at] + segment(0xE1, b"Exif\x00\x00" + exif.tobytes()) + jpeg[at:]
    else:
        options = {"quality": quality, "progressive": progressive}
        if restart:
            options["restart_marker_blocks"] = restart
        if exif is not None:
            options["exif"] = exif.tobytes()
        buffer = io.BytesIO()
        Image.fromarray(image if grey else image[..., ::-1]).save(buffer, "JPEG", **options)
        jpeg = buffer.getvalue()
    extra = jpeg
    if draw(st.booleans()):  # a comment holding 0xFF 0xD9 before the last scan
        last = scan_starts(extra)[-1]
        extra = extra[:last] + segment(0xFE, COMMENT) + extra[last:]
    if draw(st.booleans()) and extra[2:4] == b"\xff\xe0":  # a JFXX thumbnail after JFIF's APP0
        at = 4 + int.from_bytes(extra[4:6], "big")
        extra = extra[:at] + segment(0xE0, b"JFXX\x00\x10" + thumbnail()) + extra[at:]
    return jpeg, extra


def progressive_with_comment() -> tuple[bytes, bytes]:
    """A progressive OpenCV JPEG with COMMENT before its last scan."""
    image = np.random.default_rng(1).integers(0, 256, (24, 32, 3), np.uint8)
    jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    last = scan_starts(jpeg)[-1]
    return jpeg, jpeg[:last] + segment(0xFE, COMMENT) + jpeg[last:]


def decoded(jpeg: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_UNCHANGED)


SETTINGS = settings(max_examples=40, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


@SETTINGS
@given(pair=jpegs(), tail=st.one_of(st.sampled_from(TAILS), st.binary(max_size=80)))
@example(pair=progressive_with_comment(), tail=b"\xff\xd8\xff\xe1\x00\x10maker data")
def test_a_whole_jpeg_with_bytes_after_its_end_is_read_as_encoded(tmp_path, pair, tail):
    jpeg, extra = pair
    path = tmp_path / "frame.jpg"
    path.write_bytes(extra + tail)
    assert np.array_equal(read_image(path), decoded(jpeg))


def test_a_thumbnail_and_an_mpf_image_do_not_stand_for_the_image(tmp_path):
    """A phone's JPEG: an Exif thumbnail in APP0 and a second image after the first one's
    end-of-image marker (MPF); the same cut inside its scan is refused though it ends with
    the second image's end-of-image marker, as the last bytes of the file."""
    image = np.random.default_rng(2).integers(0, 256, (32, 48, 3), np.uint8)
    jpeg = cv2.imencode(".jpg", image)[1].tobytes()
    at = 4 + int.from_bytes(jpeg[4:6], "big")
    phone = jpeg[:at] + segment(0xE0, b"JFXX\x00\x10" + thumbnail()) + jpeg[at:]
    path = tmp_path / "phone.jpg"
    path.write_bytes(phone + thumbnail())
    assert np.array_equal(read_image(path), decoded(jpeg))
    path.write_bytes(phone[:-300] + thumbnail())
    with pytest.raises(DataError, match=r"the image is cut short: .* inside the entropy-coded"):
        read_image(path)


@settings(max_examples=12, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pair=jpegs(max_side=24))
@example(pair=progressive_with_comment())
def test_a_jpeg_cut_at_any_byte_before_its_end_is_refused(tmp_path, pair):
    """Every cut of the file short of its last byte, i.e. short of a whole end-of-image
    marker, is refused and said to be cut short. Of the 1465 cuts of
    `progressive_with_comment()`, OpenCV 5.1's imread decodes 993 from a file (those past the
    first scan's header) with the rows after the cut grey; its imdecode, which `read_image`
    uses, refuses them all. The check before the marker walk took the cut right after the
    comment's 0xFF 0xD9 for a whole JPEG, which OpenCV then could not decode."""
    _, extra = pair
    path = tmp_path / "cut.jpg"
    for size in range(len(extra)):
        path.write_bytes(extra[:size])
        with pytest.raises(DataError) as info:
            read_image(path, what="colour image")
        message = str(info.value)
        assert message.startswith(f"{path}: ")
        if size >= 2:  # a JPEG's first two bytes make it one
            assert "the colour image is cut short" in message, size


def header_markers(jpeg: bytes) -> list[int]:
    """Where the markers of the segments before the first scan are, its SOS included."""
    at, found = 2, []
    while True:
        found.append(at)
        if jpeg[at + 1] == 0xDA:
            return found
        at += 2 + int.from_bytes(jpeg[at + 2:at + 4], "big")


@pytest.mark.parametrize("progressive", [0, 1])
def test_fill_bytes_before_markers_are_skipped(tmp_path, progressive):
    """0xFF fill bytes may precede any marker (ITU T.81 B.1.1.2): before each segment and
    before the end-of-image marker, the JPEG is read as encoded, not taken for a segment of
    code 0xFF."""
    image = np.random.default_rng(4).integers(0, 256, (24, 32, 3), np.uint8)
    jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_PROGRESSIVE, progressive,
                                        cv2.IMWRITE_JPEG_RST_INTERVAL, 2])[1].tobytes()
    filled = bytearray(jpeg)
    for at in reversed([*header_markers(jpeg), len(jpeg) - 2]):
        filled[at:at] = b"\xff" * 3
    path = tmp_path / "filled.jpg"
    path.write_bytes(bytes(filled))
    assert np.array_equal(read_image(path), decoded(jpeg))


def test_a_jpeg_cut_right_after_a_marker_and_padded_with_zeros_is_cut_short(tmp_path):
    """Cut after a segment's marker, the zeros of the padding read as a segment length of 0:
    called cut short, not an invalid JPEG."""
    jpeg = colour_images(1)[0]
    path = tmp_path / "cut.jpg"
    for at in header_markers(jpeg):
        path.write_bytes(jpeg[:at + 2] + bytes(4096))
        with pytest.raises(DataError, match=r"the image is cut short: .* is followed by zeros "
                                            r"only$"):
            read_image(path)


# -- Kimera-like bags ---------------------------------------------------------------------------

ROBOT, T0 = "r0", kb.T0_NS
COLOUR_TOPIC = f"/{ROBOT}/forward/color/image_raw/compressed"


def write_bag(path: Path, colour: list[bytes], fmt: str = "rgb8; jpeg compressed bgr8") -> None:
    """A bag laid out as the Kimera-like ones: colour frame k (the given bytes) at T0 +
    (k + 1) / 10 s, its depth 4 ms later, both camera_info topics, 50 Hz odometry."""
    camera = kb.PinholeCamera.from_fov(32, 24, kb.COLOR_HFOV)
    frames = len(colour)
    with Writer(path) as bag:
        conn = {key: bag.add_connection(f"/{ROBOT}/{topic}", msgtype, typestore=kb.TYPES)
                for key, (topic, msgtype) in kb.TOPICS.items()}

        def write(key, msg):
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            bag.write(conn[key], stamp, kb.TYPES.serialize_ros1(msg, kb.TOPICS[key][1]))

        for j in range(5 * (frames + 2)):  # 50 Hz: a colour frame every fifth sample
            stamp = T0 + j * 20_000_000
            write("odom", kb._odometry(kb._header(j, stamp, "odom"), "base",
                                       np.array([0.01 * j, 0.0, 0.0])))
            k = j // 5 - 1
            if j % 5 or not 0 <= k < frames:
                continue
            head = kb._header(k, stamp, "color")
            depth_head = kb._header(k, stamp + kb.DEPTH_DELAY_NS, "depth")
            mm = np.full((24, 32), 1500, "<u2")
            write("color", kb.MSG["sensor_msgs/msg/CompressedImage"](
                head, fmt, np.frombuffer(colour[k], np.uint8)))
            write("color_info", kb._camera_info(head, camera))
            write("depth", kb.MSG["sensor_msgs/msg/Image"](
                depth_head, 24, 32, "16UC1", 0, 64, mm.view(np.uint8).ravel()))
            write("depth_info", kb._camera_info(depth_head, camera))


def colour_images(n: int, ext: str = ".jpg") -> list[bytes]:
    rng = np.random.default_rng(3)
    return [cv2.imencode(ext, rng.integers(0, 256, (24, 32, 3), np.uint8))[1].tobytes()
            for _ in range(n)]


def read_frames(path: Path) -> tuple[list, DataError | None]:
    """The frames read before the bag's first DataError, and that error."""
    frames = []
    with RobotBags([path], ROBOT) as bags:
        try:
            for frame in bags.frames(rate=None):
                frames.append(frame)
        except DataError as err:
            return frames, err
    return frames, None


@settings(max_examples=10, deadline=None)
@given(share=st.floats(0.0, 1.0, exclude_max=True), padded=st.booleans())
@example(share=0.5, padded=False)
@example(share=0.5, padded=True)
def test_a_bag_image_cut_short_is_refused_naming_the_message(share, padded):
    """A JPEG message cut short, or cut short and padded with zeros to a fixed size (as a
    camera driver's MJPEG buffer can be), is refused, naming the topic, the message's index
    on it and its time. OpenCV 5.1's imdecode refuses the first kind, but decodes most of the
    second (960 of the 1577 cuts of this frame, padded to 4 kB) with the rest of its rows made
    up, and the reader before the marker walk took those."""
    import tempfile

    images = colour_images(5)
    whole = images[3]
    size = 2 + int(share * (len(whole) - 2))  # its SOI kept: a JPEG, from 2 bytes on
    images[3] = whole[:size] + (bytes(4096 - size) if padded else b"")
    with tempfile.TemporaryDirectory(prefix="jpeg-bag-") as folder:
        path = Path(folder) / f"{ROBOT}.bag"
        write_bag(path, images)
        frames, error = read_frames(path)
    assert error is not None and str(error).startswith(
        f"{COLOUR_TOPIC} message 3 at t = {(T0 + 400_000_000) * 1e-9:.3f} s: the colour image "
        f"is cut short: a JPEG of {len(images[3])} bytes")
    assert len(frames) == 3  # the frames before it, as encoded
    for frame, jpeg in zip(frames, images, strict=False):
        assert np.array_equal(frame.rgb, decoded(jpeg)[..., ::-1])


def test_a_bag_image_with_bytes_after_its_end_decodes_and_a_png_cut_short_is_named(tmp_path):
    images = colour_images(3)
    images[1] += b"\xff\xd8\xff\xe1\x00\x10maker data"
    write_bag(tmp_path / "jpeg.bag", images)
    frames, error = read_frames(tmp_path / "jpeg.bag")
    assert error is None and len(frames) == 3
    assert np.array_equal(frames[1].rgb, decoded(images[1])[..., ::-1])
    pngs = colour_images(3, ".png")
    pngs[2] = pngs[2][:-40]
    write_bag(tmp_path / "png.bag", pngs, "rgb8; png compressed bgr8")
    frames, error = read_frames(tmp_path / "png.bag")
    assert len(frames) == 2 and str(error) == (
        f"{COLOUR_TOPIC} message 2 at t = {(T0 + 300_000_000) * 1e-9:.3f} s: cannot decode the "
        "'rgb8; png compressed bgr8' image")
