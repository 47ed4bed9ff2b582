"""Raw frames in ``frames/``: lossless 16-bit PNG plus a JSON sidecar, each created once and never
replaced; a frame counts when the journal holds its line with both files' sha256 (docs/sessions.md).

Order matters for a crash: image, then sidecar, then the journal line. Files without a journal line are
leftovers of an interrupted frame; a resumed run takes the frame again under the next free attempt
number instead of touching them.
"""

from __future__ import annotations

import hashlib
import json
import re
import struct
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.files import atomic_create_bytes, read_regular
from hlr_lab.session.events import JournalLine, StoredFiles

FRAMES = "frames"
# zlib level 1, no row filter, run-length matching: 30 ms and 1.9 MB for a 1280×960×3 16-bit frame here,
# where the default settings take 100 ms for 2.1 MB (measured; noise makes raw frames compress poorly)
_PNG_FAST = [
    cv2.IMWRITE_PNG_COMPRESSION, 1,
    cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE,
    cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
]  # fmt: skip


@dataclass(frozen=True)
class StoredFrame:
    """A frame's two files, relative to the session directory, with their SHA-256 checksums."""

    file: str
    sha256: str
    sidecar: str
    sidecar_sha256: str

    def files(self) -> StoredFiles:
        """The part of the frame's journal line that names its files."""
        return StoredFiles(
            file=self.file, sha256=self.sha256, sidecar=self.sidecar, sidecar_sha256=self.sidecar_sha256
        )


def store_frame(session: Path, name: str, pixels: np.ndarray, sidecar: Mapping[str, object]) -> StoredFrame:
    """Write ``frames/NAME.png`` and ``frames/NAME.json``; :class:`FileExistsError` if either exists.

    pixels: (H, W, 3) RGB or (H, W) uint8/uint16 raw values, stored bit for bit. sidecar: a session
    frame's :class:`~hlr_lab.session.events.Sidecar`, or a calibration photograph's own record.
    """
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name) or ".." in name:
        raise ValueError(
            f"{name!r} is not a frame name (letters, digits, _ . -): nothing is written outside frames/"
        )
    if pixels.dtype not in (np.uint8, np.uint16) or pixels.ndim not in (2, 3):
        raise TypeError(f"raw frames are (H, W[, 3]) uint8 or uint16, not {pixels.dtype} {pixels.shape}")
    bgr = pixels[..., ::-1] if pixels.ndim == 3 else pixels  # OpenCV stores BGR
    ok, png = cv2.imencode(".png", np.ascontiguousarray(bgr), _PNG_FAST)
    if not ok:
        raise OSError(f"PNG encoding of frame {name} failed")
    image = png.tobytes()
    image_sha256 = _sha256(image)  # the sidecar vouches for its image: a journal line must agree with both
    meta = (json.dumps({**sidecar, "image_sha256": image_sha256}, indent=1, sort_keys=True) + "\n").encode()
    image_path, sidecar_path = f"{FRAMES}/{name}.png", f"{FRAMES}/{name}.json"
    atomic_create_bytes(session / image_path, image)
    atomic_create_bytes(session / sidecar_path, meta)
    return StoredFrame(image_path, image_sha256, sidecar_path, _sha256(meta))


def frame_problem(session: Path, event: JournalLine) -> str | None:
    """Why a journaled frame cannot be trusted (a file missing or changed, a sidecar that disagrees with
    its journal line), or None when it is intact. ``event`` is a checked journal frame line."""
    return checked_sidecar(session, event)[1] or _checked_image(session, event)[1]


def load_frame(session: Path, event: JournalLine, size: tuple[int, int] | None = None) -> np.ndarray:
    """The pixels of a journaled frame, its image checked against the journal as it is read (once), and
    (given ``size``, width × height in pixels) its size from the PNG header before it is decoded: a
    60000 × 60000 image with a consistent checksum is refused, not decoded."""
    image, problem = _checked_image(session, event)
    if problem:
        raise InputError(f"{problem}; run hlr-lab acquire again on this session to retake it", path=session)
    header = png_size(image)
    if size is not None and header is not None and header != size:
        raise InputError(
            f"{event['file']}: it is {header[0]}×{header[1]} pixels, the rig's camera {size[0]}×{size[1]}; it is "
            "not the frame this rig took — restore the session's frame, or delete it and its journal line is set "
            "aside when hlr-lab acquire runs on the session again",
            path=session,
        )
    damage = png_damage(image)  # libpng would print its own line to the console, then OpenCV return None
    pixels = None if damage else cv2.imdecode(np.frombuffer(image, np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        why = damage or "OpenCV cannot decode it"
        raise InputError(
            f"{event['file']} is not a whole PNG image although its checksum matches ({why}); restore the "
            "session's frame, or delete it and its journal line is set aside when hlr-lab acquire runs on the "
            "session again",
            path=session,
        )
    return pixels[..., ::-1] if pixels.ndim == 3 else pixels


def png_size(image: bytes) -> tuple[int, int] | None:
    """(width, height) in pixels from a PNG's IHDR chunk, or None when ``image`` does not start as a PNG."""
    if len(image) < 24 or image[:8] != b"\x89PNG\r\n\x1a\n" or image[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", image[16:24])
    return width, height


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_damage(image: bytes) -> str | None:
    """What makes ``image`` not a whole PNG (a chunk cut short or failing its CRC, a chunk missing), or None.
    Checked before decoding so that a damaged or truncated frame is one clear error, not libpng's own line on
    the console. The CRCs cost ~1 ms a frame; inflating the image data to check it too would double the
    decoding time of every fit, so a stream damaged *and* given fresh CRCs is left to libpng."""
    if not image.startswith(_PNG_SIGNATURE):
        return "no PNG signature"
    at, kinds, view = len(_PNG_SIGNATURE), [], memoryview(image)  # a view: the image data is not copied
    while at < len(image):
        if at + 12 > len(image):
            return f"cut short at byte {at}"
        (length, kind) = struct.unpack(">I4s", view[at : at + 8])
        name = repr(kind)[2:-1]  # four bytes of anything: a line break is shown escaped
        if at + 12 + length > len(image):
            return f"its {name} chunk is cut short"
        (crc,) = struct.unpack(">I", view[at + 8 + length : at + 12 + length])
        if zlib.crc32(view[at + 8 : at + 8 + length], zlib.crc32(kind)) != crc:
            return f"its {name} chunk fails its CRC"
        kinds.append(kind)
        at += 12 + length
        if kind == b"IEND":
            break
    if not kinds or kinds[0] != b"IHDR" or kinds[-1] != b"IEND" or b"IDAT" not in kinds:
        return "it lacks its IHDR, IDAT or IEND chunk"
    return None


# what a journal frame line and its sidecar must both say
_AGREE = ("pose", "exposure_index", "dark", "exposure_s")


def checked_sidecar(session: Path, event: JournalLine) -> tuple[JournalLine | None, str | None]:
    """The sidecar of a journaled frame, and why the frame cannot be trusted (None when it can): its
    image is there, the sidecar matches its checksum, is a JSON object and agrees with the journal line
    (pose, exposure, lamp, and its image's checksum). The image itself is checked when it is read
    (:func:`load_frame`), so that a fit reads each image once."""
    if not (session / event["file"]).is_file():
        return None, f"{event['file']} is missing"
    try:
        data = read_regular(session / event["sidecar"])  # not through a link, nor from a FIFO or a device
    except FileNotFoundError:
        return None, f"{event['sidecar']} is missing"
    if _sha256(data) != event["sidecar_sha256"]:
        return None, f"{event['sidecar']} does not match its checksum in the journal"
    try:
        sidecar = json.loads(data)
    except ValueError:
        sidecar = None
    if not isinstance(sidecar, dict):
        return None, f"{event['sidecar']} is not a JSON object"
    if sidecar.get("image_sha256") != event["sha256"]:
        return None, f"{event['sidecar']} describes another image than {event['file']}"
    differ = [k for k in _AGREE if sidecar.get(k) != event[k]]
    if differ:
        return None, f"the journal line of {event['file']} and its sidecar disagree on {', '.join(differ)}"
    return sidecar, None


def _checked_image(session: Path, event: JournalLine) -> tuple[bytes, str | None]:
    """The image file's bytes, and why they cannot be trusted (None when they match the journal)."""
    try:
        data = read_regular(session / event["file"])
    except FileNotFoundError:
        return b"", f"{event['file']} is missing"
    if _sha256(data) != event["sha256"]:
        return b"", f"{event['file']} does not match its checksum in the journal"
    return data, None


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()
