"""A pose's merged radiance as an OpenEXR file a graphics tool opens without hlr-lab.

One file per pose (docs/formats.md, "radiance/POSE.exr"): the HDR merge's linear radiance as float32
channels R, G, B (0 where no frame of the bracket was usable), and two masks as half-float 0/1 layers:
``mask.usable`` (some frame was usable) and ``mask.fit`` (the pixel is one the fit used). ZIP-compressed,
scan lines. The header carries what a user needs to use the values: the pose, the turntable angle, the lamp's
position and power, the bracket's exposures and gains, the camera's matrix and distortion, the values'
units and the hlr-lab version — typed attributes for tools that list them, and all of it again as one JSON
string (``hlrLab``) at full precision.
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import OpenEXR

from hlr_lab import __version__
from hlr_lab.files import atomic_write_bytes

UNITS = (
    "linear radiance in the rig's units: DN per second of exposure at 0 dB gain, black level subtracted, "
    "divided by [sensor] sensitivity (so that I / L of a white Lambertian surface is cos α)"
)


@dataclass(frozen=True)
class RadianceHeader:
    """What a radiance file says of its pose. Lengths in metres, angles in degrees, times in seconds."""

    pose: str
    turntable_deg: float
    lamp_m: tuple[float, float, float]  # the lamp where the servos measured it, world frame
    lamp_power: float  # Φ, the rig file's power times the lamp output the run measured
    exposures_s: tuple[float, ...]  # the bracket, as its sidecars recorded it
    gains_db: tuple[float, ...]
    camera_matrix: tuple[tuple[float, ...], ...]  # (3, 3) K, pixels
    distortion: tuple[float, ...]  # OpenCV (k1, k2, p1, p2[, k3])
    units: str = UNITS
    hlr_lab: str = __version__


@dataclass(frozen=True)
class RadianceImage:
    """A radiance file read back: value (H, W, 3) float32, usable and fit (H, W) bool, and its header."""

    value: np.ndarray
    usable: np.ndarray
    fit: np.ndarray
    header: RadianceHeader


def write_radiance(
    path: Path, value: np.ndarray, usable: np.ndarray, fit: np.ndarray, header: RadianceHeader
) -> None:
    """Write one pose's radiance to ``path`` (.exr) atomically (:func:`hlr_lab.files.atomic_write_bytes`:
    a temporary beside it, renamed over it; a symbolic link refused, a full disk said so).

    Parameters
    ----------
    value : (H, W, 3) float
        Linear radiance (NaN where unusable: written as 0).
    usable, fit : (H, W) bool
        Where some frame was usable; which pixels the fit used.
    """
    h, w = usable.shape
    if value.shape != (h, w, 3) or fit.shape != (h, w):
        raise ValueError(f"radiance {value.shape}, usable {usable.shape} and fit {fit.shape} do not agree")
    rgb = np.where(usable[..., None] & np.isfinite(value), value, 0.0).astype(np.float32)
    channels = {
        "R": rgb[..., 0].copy(),
        "G": rgb[..., 1].copy(),
        "B": rgb[..., 2].copy(),
        "mask.usable": usable.astype(np.float16),
        "mask.fit": fit.astype(np.float16),
    }
    attributes = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "hlrLabPose": header.pose,
        "hlrLabTurntableDeg": float(header.turntable_deg),
        "hlrLabLampM": np.asarray(header.lamp_m, np.float64),
        "hlrLabExposuresS": [float(t) for t in header.exposures_s],
        "hlrLabCameraMatrix": np.asarray(header.camera_matrix, np.float64),
        "hlrLabUnits": header.units,
        "hlrLab": json.dumps(asdict(header)),
    }
    encoded = io.BytesIO()
    with OpenEXR.File(attributes, channels) as f:
        f.write(encoded)
    atomic_write_bytes(path, encoded.getvalue())


def read_radiance(path: Path) -> RadianceImage:
    """Read a file :func:`write_radiance` wrote; ValueError naming it when it is not one."""
    with OpenEXR.File(str(path)) as f:
        header, channels = f.header(), f.channels()
        if "hlrLab" not in header or not {"RGB", "mask.usable", "mask.fit"} <= set(channels):
            raise ValueError(f"{path}: not an hlr-lab radiance file (no hlrLab header or channels)")
        value = np.array(channels["RGB"].pixels, np.float32)
        usable = np.asarray(channels["mask.usable"].pixels) > 0.5
        fit = np.asarray(channels["mask.fit"].pixels) > 0.5
        meta = json.loads(header["hlrLab"])
    lamp = tuple(float(x) for x in meta["lamp_m"])
    header = RadianceHeader(
        pose=str(meta["pose"]),
        turntable_deg=float(meta["turntable_deg"]),
        lamp_m=(lamp[0], lamp[1], lamp[2]),
        lamp_power=float(meta["lamp_power"]),
        exposures_s=tuple(float(t) for t in meta["exposures_s"]),
        gains_db=tuple(float(g) for g in meta["gains_db"]),
        camera_matrix=tuple(tuple(float(x) for x in row) for row in meta["camera_matrix"]),
        distortion=tuple(float(x) for x in meta["distortion"]),
        units=str(meta["units"]),
        hlr_lab=str(meta["hlr_lab"]),
    )
    return RadianceImage(value, usable, fit, header)
