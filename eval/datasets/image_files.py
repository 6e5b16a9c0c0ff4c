"""Image files of the RGB-D data sets (7-Scenes, TUM RGB-D, NYU, Redwood), decoded whole or
refused with a `DataError` naming the file.

OpenCV does not refuse every JPEG that was cut short (an interrupted download or copy):
`cv2.imread` decodes one from a file with the missing rows grey (libjpeg only prints "Premature
end of JPEG file"), and `cv2.imdecode`, which refuses one whose bytes simply end (OpenCV 5.1),
decodes one followed by other bytes, such as zero padding or another JPEG, and makes up the
rest of its rows. So a file is read whole and a JPEG is walked marker by marker
(`jpeg_defect`) before its bytes are decoded from memory: it must reach the end-of-image marker
after its last scan. Whatever follows that marker (the thumbnails, MPF images and maker data
that cameras and phones append, padding) is ignored, as decoders ignore it. PNG, PPM and PGM
files cut short fail to decode and are refused as unreadable.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from tcaff_gtsam.errors import DataError

__all__ = ["JPEG_START", "jpeg_defect", "read_image"]

JPEG_START = b"\xff\xd8"  # the start-of-image marker (SOI) every JPEG begins with
_EOI, _SOS, _SOI, _TEM = 0xD9, 0xDA, 0xD8, 0x01  # marker codes (the byte after 0xFF)
_NAMES = {0xC4: "DHT", 0xCC: "DAC", 0xDA: "SOS", 0xDB: "DQT", 0xDC: "DNL", 0xDD: "DRI",
          0xDE: "DHP", 0xDF: "EXP", 0xFE: "COM",
          **{code: f"SOF{code - 0xC0}" for code in range(0xC0, 0xD0)
             if code not in (0xC4, 0xC8, 0xCC)},
          **{code: f"APP{code - 0xE0}" for code in range(0xE0, 0xF0)}}

# A marker: 0xFF followed by a code other than 0x00, 0xD0-0xD7 and 0xFF. Inside entropy-coded
# data a 0xFF byte is followed by 0x00 (a stuffed data byte) or 0xD0-0xD7 (a restart marker,
# RSTm, which belongs to the scan); 0xFF is a fill byte, which may precede any marker; any other
# byte after 0xFF is a marker that ends the scan (ITU T.81, B.1.1.2, B.1.1.5, F.1.2.3). Where a
# marker is due but other bytes come first, they are skipped the same way, as libjpeg does.
# re's search skips to each 0xFF byte in C: on 640 x 480 frames, some 25 us per 40-50 kB
# baseline JPEG and 100-130 us per progressive one with restart markers every 8 MCUs, where a
# loop of bytes.find over the 0xFF bytes took 23 and 730 us (scripts/bench_image_files.py).
_MARKER = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")


def jpeg_defect(data: bytes) -> str | None:
    """None if `data` is a whole JPEG or no JPEG at all (other formats: not beginning with the
    SOI marker), else what is wrong with it, as words that follow "the image" ("is cut
    short: ...").

    The marker segments are walked from the start (ITU T.81 B.2, JFIF): each one that carries
    a length (APPn, DQT, SOFn, DHT, DRI, COM, SOS, ...) is skipped by it, so that an
    end-of-image marker inside one (an Exif thumbnail) is not taken for the image's; the
    entropy-coded data after each SOS (several in a progressive JPEG) runs to the next marker.
    The JPEG is whole when an EOI marker follows its last scan; bytes after it are ignored. It
    is cut short when the data end first: inside a scan, inside a segment or its length, with
    a segment whose length runs past the end, or at a second SOI marker (the rest cut away
    and another JPEG after it, which OpenCV decodes as the end of the first one's scan).
    """
    if not data.startswith(JPEG_START):
        return None
    n = len(data)
    pos, scans, where = len(JPEG_START), 0, "after its start-of-image marker"
    while True:
        found = _MARKER.search(data, pos)  # the next marker at or after pos
        if found is None:
            return (f"is cut short: a JPEG of {n} bytes that ends {where}, before its "
                    "end-of-image marker")
        at = found.end() - 1  # its code byte
        code = data[at]
        if code == _EOI:
            return None
        if code == _SOI:  # a JPEG begins only once: what was cut short runs into another
            return (f"is cut short: a JPEG of {n} bytes that ends {where}, at byte {at - 1}, "
                    "where another begins (a start-of-image marker), before its end-of-image "
                    "marker")
        if code == _TEM:  # the one marker without a segment outside a scan
            pos = at + 1
            continue
        name = _NAMES.get(code, f"0xFF{code:02X}")
        if at + 3 > n:
            return (f"is cut short: a JPEG of {n} bytes that ends inside the length of its "
                    f"{name} segment at byte {at - 1}")
        length = data[at + 1] << 8 | data[at + 2]  # big-endian, counting its own 2 bytes
        if length < 2:
            if not data[at + 1:].strip(b"\0"):  # cut after the marker, padded with zeros
                return (f"is cut short: a JPEG of {n} bytes whose {name} marker at byte "
                        f"{at - 1} is followed by zeros only")
            return (f"is not a valid JPEG: its {name} segment at byte {at - 1} gives a length "
                    f"of {length}")
        pos = at + 1 + length
        if pos > n:
            return (f"is cut short: a JPEG of {n} bytes whose {name} segment at byte {at - 1} "
                    f"runs to byte {pos}, past its end")
        if code == _SOS:
            scans += 1
            where = f"inside the entropy-coded data of scan {scans} (SOS at byte {at - 1})"
        else:
            where = f"after its {name} segment at byte {at - 1}"


def read_image(path: Path, flags: int = cv2.IMREAD_UNCHANGED, what: str = "image"
               ) -> np.ndarray:
    """The image in the file at `path`, as OpenCV decodes it with `flags` (colour in BGR
    order; (H, W) or (H, W, C), of the file's dtype with IMREAD_UNCHANGED).

    Args:
        what: what the file holds, for the messages ("colour image").
    Raises:
        DataError: naming the file: it is missing or not a regular file, cannot be read, is a
            JPEG cut short (`jpeg_defect`), or is not an image OpenCV decodes.
    """
    if not path.is_file():  # a FIFO would block the read
        raise DataError(f"{path}: no such {what}")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    if (defect := jpeg_defect(data)) is not None:
        raise DataError(f"{path}: the {what} {defect}")
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error:  # an empty file among others
        image = None
    if image is None:
        raise DataError(f"{path}: cannot read the {what} (not an image OpenCV decodes)")
    return image
