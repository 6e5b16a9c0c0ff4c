"""Image files of the RGB-D data sets (7-Scenes, TUM RGB-D, NYU, Redwood), decoded whole or
refused with a `DataError` naming the file.

`cv2.imread` decodes a JPEG that was cut short (an interrupted download or copy) without
failing: libjpeg only prints "Premature end of JPEG file" and OpenCV fills the missing rows
grey. So a file is read whole, a JPEG that does not end with its end-of-image marker (zero
bytes of padding after it aside) is refused, and the bytes are decoded from memory. PNG, PPM
and PGM files cut short fail to decode and are refused as unreadable.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from tcaff_gtsam.errors import DataError

__all__ = ["read_image"]

_JPEG_START = b"\xff\xd8"  # the start-of-image marker every JPEG begins with
# The end-of-image marker. A file cut short inside its compressed data cannot end with it:
# there a 0xFF byte is always followed by 0x00 or a restart marker (0xD0..0xD7).
_JPEG_END = b"\xff\xd9"


def read_image(path: Path, flags: int = cv2.IMREAD_UNCHANGED, what: str = "image"
               ) -> np.ndarray:
    """The image in the file at `path`, as OpenCV decodes it with `flags` (colour in BGR
    order; (H, W) or (H, W, C), of the file's dtype with IMREAD_UNCHANGED).

    Args:
        what: what the file holds, for the messages ("colour image").
    Raises:
        DataError: naming the file: it is missing or not a regular file, cannot be read, is a
            JPEG cut short, or is not an image OpenCV decodes.
    """
    if not path.is_file():  # a FIFO would block the read
        raise DataError(f"{path}: no such {what}")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    # some writers pad a JPEG with zero bytes after its end-of-image marker
    if data.startswith(_JPEG_START) and not data.rstrip(b"\x00").endswith(_JPEG_END):
        raise DataError(f"{path}: the {what} is cut short: a JPEG file of {len(data)} bytes "
                        "that does not end with the end-of-image marker")
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), flags) if data else None
    except cv2.error:
        image = None
    if image is None:
        raise DataError(f"{path}: cannot read the {what} (not an image OpenCV decodes)")
    return image
