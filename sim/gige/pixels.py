"""Pixel formats as a GigE Vision camera sends them (GenICam PFNC): the simulated sensor's (H, W, 3)
digital numbers laid out byte by byte.

The simulated sensor is a colour one that delivers RGB (a camera that interpolates its Bayer mosaic
itself); asked for a Bayer format it sends the RGGB mosaic of that frame, and asked for a mono format,
its green channel. Packed 12-bit formats put two pixels in three bytes, in PFNC's order (``Mono12p``,
``BayerRG12p``: least significant bits first) or GigE Vision's older one (``Mono12Packed``: the high
eight bits of each pixel, then both low nibbles in one byte).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PixelFormat:
    """One PFNC pixel format: its 32-bit code, channels delivered, significant bits, and layout."""

    name: str
    code: int  # PFNC value; bits 16–23 are the bits a pixel occupies
    channels: int  # 1: mono or Bayer mosaic; 3: RGB
    bits: int  # significant bits per channel value
    layout: str  # "8", "16" (little-endian words), "12p" (PFNC packed), "12packed" (GigE Vision packed)

    @property
    def bits_per_pixel(self) -> int:
        return (self.code >> 16) & 0xFF

    def payload_bytes(self, width: int, height: int) -> int:
        return width * height * self.bits_per_pixel // 8


FORMATS = {
    f.name: f
    for f in (
        PixelFormat("Mono8", 0x01080001, 1, 8, "8"),
        PixelFormat("Mono12", 0x01100005, 1, 12, "16"),
        PixelFormat("Mono16", 0x01100007, 1, 16, "16"),
        PixelFormat("Mono12p", 0x010C0047, 1, 12, "12p"),
        PixelFormat("Mono12Packed", 0x010C0006, 1, 12, "12packed"),
        PixelFormat("BayerRG12", 0x01100011, 1, 12, "16"),
        PixelFormat("BayerRG16", 0x0110002F, 1, 16, "16"),
        PixelFormat("BayerRG12p", 0x010C0059, 1, 12, "12p"),
        PixelFormat("RGB8", 0x02180014, 3, 8, "8"),
        PixelFormat("RGB12", 0x0230001A, 3, 12, "16"),
        PixelFormat("RGB16", 0x02300033, 3, 16, "16"),
    )
}
BY_CODE = {f.code: f for f in FORMATS.values()}


def sensor_values(frame: np.ndarray, fmt: PixelFormat, sensor_bits: int) -> np.ndarray:
    """(H, W, 3) sensor DN of ``sensor_bits`` bits → the (H, W, fmt.channels) values ``fmt`` carries:
    scaled by a shift to its bits (a 12-bit sensor in Mono16 uses the top twelve), a mosaic for Bayer."""
    if fmt.name.startswith("Bayer"):
        h, w, _ = frame.shape
        channel = np.ones((h, w), np.intp)  # green on the RGGB checkerboard's other two sites
        channel[0::2, 0::2], channel[1::2, 1::2] = 0, 2
        values = np.take_along_axis(frame, channel[..., None], axis=2)
    elif fmt.channels == 1:
        values = frame[..., 1:2]
    else:
        values = frame
    shift = fmt.bits - sensor_bits
    values = values.astype(np.uint32)
    return (values << shift if shift >= 0 else values >> -shift).astype(np.uint16)


def test_pattern(height: int, width: int, fmt: PixelFormat) -> np.ndarray:
    """The ``GreyDiagonalRamp`` test pattern, (H, W, channels): value (17·x + 29·y + 997·c) mod 2^bits at
    column x, row y, channel c — every bit of a value changes somewhere, and channels differ, so a byte
    order, packing or channel order error shows."""
    y, x, c = np.ogrid[:height, :width, : fmt.channels]
    return ((17 * x + 29 * y + 997 * c) % (1 << fmt.bits)).astype(np.uint16)


def encode(values: np.ndarray, fmt: PixelFormat) -> bytes:
    """(H, W, channels) values → the payload bytes of ``fmt`` (rows top to bottom, channels interleaved)."""
    flat = np.ascontiguousarray(values, dtype=np.uint16).reshape(-1)
    if fmt.layout == "8":
        return flat.astype(np.uint8).tobytes()
    if fmt.layout == "16":
        return flat.astype("<u2").tobytes()
    a, b = flat[0::2].astype(np.uint32), flat[1::2].astype(np.uint32)  # pixel pairs (width × height even)
    if fmt.layout == "12p":  # a 24-bit little-endian word holding a in bits 0–11, b in bits 12–23
        word = a | (b << 12)
        packed = np.stack([word & 0xFF, (word >> 8) & 0xFF, word >> 16], axis=1)
    else:  # "12packed": a's high byte, both low nibbles (a's in bits 0–3), b's high byte
        packed = np.stack([a >> 4, (a & 0xF) | ((b & 0xF) << 4), b >> 4], axis=1)
    return packed.astype(np.uint8).tobytes()
