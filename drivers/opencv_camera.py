"""A camera through OpenCV's VideoCapture: V4L2/UVC devices with manual exposure and gain, raw frames of
8 to 16 bits.

* Controls are applied at the next capture and read back; a value the device did not take is a
  :class:`DeviceFault` naming the control (auto exposure left on, a control the driver lacks). After a
  change, ``stale_frames`` frames are discarded: V4L2 queues frames that were exposed before it.
* V4L2 units: exposure in ``exposure_unit_s`` steps (``exposure_time_absolute``: 100 µs), manual mode is
  ``CAP_PROP_AUTO_EXPOSURE`` = 1, gain in device units (``gain_per_db`` of them per dB). Cameras differ:
  ``v4l2-ctl -d /dev/video0 -l`` lists the controls, their ranges and units.
* Frame formats: with a raw ``fourcc`` ("Y16 ", "GREY", "Y10 ", "Y12 ") OpenCV's RGB conversion is turned
  off and the buffer is decoded here (:func:`decode_frame`); 10/12-bit values come in 16-bit words, at the
  bottom or (``msb_aligned``) at the top.
* ``backend="images"`` reads an image sequence (``frames/%04d.png``) through the same code: how the
  capture and decoding are tested where no camera is attached. Such a source has no controls, and says
  so when asked to set one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from drivers.errors import DeviceError, DeviceFault, DeviceTimeout, LimitError
from drivers.protocols import RawFrame

BACKENDS = {"v4l2": cv2.CAP_V4L2, "images": cv2.CAP_IMAGES, "any": cv2.CAP_ANY}
RAW_FOURCCS = ("Y16 ", "GREY", "Y10 ", "Y12 ", "Y8  ")


@dataclass(frozen=True)
class OpenCVCameraConfig:
    """A V4L2/UVC camera (or an image sequence) through OpenCV: the device, the size and pixel format to
    ask for, and how its values are packed."""

    device: str  # "/dev/video0", a camera index "0", or (backend "images") a sequence pattern
    backend: Literal["v4l2", "images", "any"] = "v4l2"
    width: int | None = None
    height: int | None = None
    fourcc: str | None = None  # the pixel format to ask for, e.g. "Y16 "; None: the device's default
    bits: int = 8  # significant bits per value: 8, 10, 12 or 16
    msb_aligned: bool = False  # 10/12-bit values at the top of their 16-bit words
    exposure_unit_s: float = 1e-4
    exposure_range_s: tuple[float, float] = (1e-4, 10.0)
    manual_exposure: float = 1.0  # the CAP_PROP_AUTO_EXPOSURE value meaning "manual" (V4L2: 1)
    gain_per_db: float = 1.0
    max_gain_db: float = 24.0
    stale_frames: int = 2


QUIET_LOG_LEVEL = cv2.utils.logging.LOG_LEVEL_ERROR


class OpenCVCamera:
    """A :class:`~drivers.protocols.Camera` through OpenCV's VideoCapture (webcams: exposure control and
    raw data only as far as the device gives them)."""

    def __init__(self, config: OpenCVCameraConfig):
        if config.bits not in (8, 10, 12, 16):
            raise ValueError(f"bits must be 8, 10, 12 or 16, not {config.bits}")
        self.config = config
        source = int(config.device) if config.device.isdigit() else config.device
        # OpenCV prints its own warnings on stderr when a device does not open; this driver's error says it
        cv2.utils.logging.setLogLevel(QUIET_LOG_LEVEL)
        self._cap = cv2.VideoCapture(source, BACKENDS[config.backend])
        if not self._cap.isOpened():
            raise DeviceError(
                "cannot open; check the device path (v4l2-ctl --list-devices) and that no other program "
                "holds the camera",
                device=self.name,
            )
        self.exposure_s, self.gain_db = None, None  # as last applied; None: never set by hlr-lab
        self._pending: dict[str, float] = {}
        try:
            self._set_format()
        except BaseException:
            self._cap.release()
            raise

    @property
    def name(self) -> str:
        return f"camera {self.config.device} ({self.config.backend})"

    def set_exposure(self, seconds: float) -> None:
        lo, hi = self.config.exposure_range_s
        if not lo <= seconds <= hi:
            raise LimitError(f"exposure {seconds:g} s is outside [{lo:g}, {hi:g}] s", device=self.name)
        self._request(
            "exposure", self._exposure_units(seconds) * self.config.exposure_unit_s, self.exposure_s
        )

    def set_gain(self, gain_db: float) -> None:
        if not 0 <= gain_db <= self.config.max_gain_db:
            raise LimitError(
                f"gain {gain_db:g} dB is outside [0, {self.config.max_gain_db:g}] dB", device=self.name
            )
        self._request("gain", self._gain_units(gain_db) / self.config.gain_per_db, self.gain_db)

    def capture(self) -> RawFrame:
        """The next frame exposed with the current settings (pending ones applied and checked first)."""
        if self._pending:
            self._apply(self._pending)
            self._pending = {}
            for _ in range(self.config.stale_frames):  # exposed before the change took effect
                self._cap.grab()
        ok, raw = self._cap.read()
        if not ok or raw is None:
            raise DeviceTimeout("no frame arrived; check the cable and the trigger mode", device=self.name)
        c = self.config
        pixels = decode_frame(raw, bits=c.bits, msb_aligned=c.msb_aligned, size=self._size())
        if int(pixels.max(initial=0)) >= 1 << c.bits:
            raise DeviceFault(
                f"values above {c.bits} bits; check bits and msb_aligned in the rig file",
                device=self.name,
                code=0,
            )
        return RawFrame(
            pixels,
            c.bits,
            self.exposure_s
            if self.exposure_s is not None
            else self._cap.get(cv2.CAP_PROP_EXPOSURE) * c.exposure_unit_s,
            self.gain_db if self.gain_db is not None else self._cap.get(cv2.CAP_PROP_GAIN) / c.gain_per_db,
            time.time(),
            {"backend": self._cap.getBackendName()},
        )

    def close(self) -> None:
        self._cap.release()

    # -- controls ---------------------------------------------------------------------------------------
    def _set_format(self) -> None:
        c = self.config
        if c.fourcc:
            self._control("pixel format", cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*c.fourcc))
            if c.fourcc in RAW_FOURCCS:
                self._control("raw frames (RGB conversion off)", cv2.CAP_PROP_CONVERT_RGB, 0)
        if c.width:
            self._control("frame width", cv2.CAP_PROP_FRAME_WIDTH, c.width)
        if c.height:
            self._control("frame height", cv2.CAP_PROP_FRAME_HEIGHT, c.height)

    def _request(self, control: str, value: float, applied: float | None) -> None:
        """Remember a control change for the next capture; asking for what is set already changes nothing
        (no frames are dropped for it)."""
        if applied is not None and value == applied:
            self._pending.pop(control, None)
        else:
            self._pending[control] = value

    def _exposure_units(self, seconds: float) -> int:
        return max(1, round(seconds / self.config.exposure_unit_s))

    def _gain_units(self, gain_db: float) -> int:
        return round(gain_db * self.config.gain_per_db)

    def _apply(self, pending: dict[str, float]) -> None:
        c = self.config
        if "exposure" in pending:
            units = self._exposure_units(pending["exposure"])
            self._control("manual exposure mode", cv2.CAP_PROP_AUTO_EXPOSURE, c.manual_exposure)
            self._control("exposure", cv2.CAP_PROP_EXPOSURE, units)
            self.exposure_s = units * c.exposure_unit_s
        if "gain" in pending:
            units = self._gain_units(pending["gain"])
            self._control("gain", cv2.CAP_PROP_GAIN, units)
            self.gain_db = units / c.gain_per_db

    def _control(self, what: str, prop: int, value: float) -> None:
        """Set and read back one property; refused or changed on the way is a fault naming it."""
        taken = self._cap.set(prop, value)
        back = self._cap.get(prop)
        if not taken or abs(back - value) > 0.5:
            raise DeviceFault(
                f"did not take {what} = {value:g} (reads {back:g}); list what the camera supports with "
                "v4l2-ctl -l (controls) and --list-formats-ext (formats), then adjust [camera.capture] in "
                "the rig file",
                device=self.name,
                code=0,
            )

    def _size(self) -> tuple[int, int]:
        return int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))


def decode_frame(raw: np.ndarray, *, bits: int, msb_aligned: bool, size: tuple[int, int]) -> np.ndarray:
    """OpenCV's frame → (H, W, C) sensor values, C = 1 (mono) or 3 (RGB).

    raw: (H, W) or (H, W, 3) BGR of uint8/uint16 as decoded by OpenCV, or, with RGB conversion off, the
    driver's buffer as one row of bytes (1, N): N = W·H for 8-bit, 2·W·H for 16-bit little-endian words.
    size: (W, H) of the frame, needed for the one-row buffer.
    """
    width, height = size
    if raw.ndim == 2 and raw.shape[0] == 1 and raw.dtype == np.uint8 and height > 1:
        buffer = raw.reshape(-1)
        if buffer.size == 2 * width * height:
            raw = buffer.view("<u2").reshape(height, width)
        elif buffer.size == width * height:
            raw = buffer.reshape(height, width)
        else:
            raise ValueError(
                f"a raw buffer of {buffer.size} bytes is not a {width}×{height} frame of 8 or 16 bits"
            )
    pixels = raw[..., ::-1] if raw.ndim == 3 else raw[..., None]  # OpenCV colour is BGR
    if raw.dtype == np.uint16 and bits < 16 and msb_aligned:
        pixels = pixels >> (16 - bits)
    return np.ascontiguousarray(pixels)
