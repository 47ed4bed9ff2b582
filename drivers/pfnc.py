"""Pixel formats of GenICam cameras (PFNC): the payload bytes of one frame → (H, W, C) values.

Unpacked formats carry each value in 1 or 2 little-endian bytes; packed 12-bit formats carry two
values in three bytes — PFNC's ``…12p`` least significant bits first, GigE Vision's older
``…12Packed`` the high eight bits of each value, then both low nibbles in one byte. Bayer mosaics are
interpolated to RGB (OpenCV's edge-aware demosaicing) and keep their bit depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Layout:
    """How a PFNC format lays out a frame: values per pixel, significant bits, and byte packing."""

    channels: int
    bits: int
    packing: str  # "8", "16" (little-endian words), "12p", "12packed"
    bayer: str | None = None  # the mosaic's first two sites, e.g. "RG"


FORMATS = {
    "Mono8": Layout(1, 8, "8"),
    "Mono10": Layout(1, 10, "16"),
    "Mono12": Layout(1, 12, "16"),
    "Mono14": Layout(1, 14, "16"),
    "Mono16": Layout(1, 16, "16"),
    "Mono12p": Layout(1, 12, "12p"),
    "Mono12Packed": Layout(1, 12, "12packed"),
    "RGB8": Layout(3, 8, "8"),
    "RGB8Packed": Layout(3, 8, "8"),  # GigE Vision's older name for RGB8
    "RGB10": Layout(3, 10, "16"),
    "RGB12": Layout(3, 12, "16"),
    "RGB16": Layout(3, 16, "16"),
    **{f"Bayer{p}8": Layout(1, 8, "8", p) for p in ("RG", "GR", "GB", "BG")},
    **{f"Bayer{p}{b}": Layout(1, b, "16", p) for p in ("RG", "GR", "GB", "BG") for b in (10, 12, 16)},
    **{f"Bayer{p}12p": Layout(1, 12, "12p", p) for p in ("RG", "GR", "GB", "BG")},
    **{f"Bayer{p}12Packed": Layout(1, 12, "12packed", p) for p in ("RG", "GR", "GB", "BG")},
}

# OpenCV names a mosaic by the second row's second and third sites: GenICam's "RG" is its "BG"
_DEMOSAIC = {"RG": cv2.COLOR_BayerBG2RGB, "GR": cv2.COLOR_BayerGB2RGB, "GB": cv2.COLOR_BayerGR2RGB,
             "BG": cv2.COLOR_BayerRG2RGB}  # fmt: skip


def payload_bytes(name: str, width: int, height: int) -> int:
    """Bytes of one ``width`` × ``height`` image in format ``name``."""
    layout = FORMATS[name]
    bits_per_value = {"8": 8, "16": 16}.get(layout.packing, 12)
    return width * height * layout.channels * bits_per_value // 8


def decode(data: bytes | memoryview, name: str, width: int, height: int) -> np.ndarray:
    """The image in ``data`` (at least :func:`payload_bytes` long; chunks after it are ignored) as
    (height, width, C) uint16 values of the format's bit depth: C = 3 for RGB and Bayer, 1 for mono.
    A payload too short for its format raises ValueError."""
    layout = FORMATS[name]
    n = width * height * layout.channels
    need = payload_bytes(name, width, height)
    if len(data) < need:
        raise ValueError(f"a {width} × {height} {name} frame needs {need} bytes, got {len(data)}")
    raw = np.frombuffer(data, np.uint8, count=need)
    if layout.packing == "8":
        values = raw.astype(np.uint16)
    elif layout.packing == "16":
        values = raw.view("<u2").astype(np.uint16)
    else:
        b0, b1, b2 = (raw[i::3].astype(np.uint16) for i in range(3))
        values = np.empty(n, np.uint16)
        if layout.packing == "12p":
            values[0::2], values[1::2] = b0 | ((b1 & 0xF) << 8), (b1 >> 4) | (b2 << 4)
        else:
            values[0::2], values[1::2] = (b0 << 4) | (b1 & 0xF), (b2 << 4) | (b1 >> 4)
    image = values.reshape(height, width, layout.channels)
    if layout.bayer is None:
        return image
    return cv2.cvtColor(image[..., 0], _DEMOSAIC[layout.bayer])
