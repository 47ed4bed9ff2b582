"""The rig's geometry, as planning needs it: camera, light gantry sphere and limits, turntable limits.

Read from ``rig.toml`` (DESIGN §4); the simulated rig ships as package data (``--sim``).
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from hlr_lab.camera import Camera
from hlr_lab.formats.io import check_header, read_toml, validate

RIG_FORMAT = "hlr-lab.rig"
SIM_RIG = "sim-rig.toml"

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Limits = Annotated[list[float], Field(min_length=2, max_length=2)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class _Header(_Strict):
    format: Literal["hlr-lab.rig"]
    version: Literal[1]
    name: str = "rig"


class _CameraSection(_Strict):
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    matrix: Annotated[list[Vec3], Field(min_length=3, max_length=3)]
    distortion: Annotated[list[float], Field(max_length=5)] = []
    position_m: Vec3
    look_at_m: Vec3
    up: Vec3 = [0.0, 0.0, 1.0]
    exposure_bracket_s: Annotated[list[Annotated[float, Field(gt=0)]], Field(min_length=1)] = [0.01]


class _GantrySection(_Strict):
    centre_m: Vec3
    arm_radius_m: float = Field(gt=0)
    azimuth_limits_deg: Limits
    elevation_limits_deg: Limits
    camera_keepout_deg: float = Field(ge=0, lt=90)
    min_light_height_m: float = 0.0

    @model_validator(mode="after")
    def _ordered(self):
        for name in ("azimuth_limits_deg", "elevation_limits_deg"):
            lo, hi = getattr(self, name)
            if lo >= hi:
                raise ValueError(f"{name}: the lower limit {lo} must be below the upper {hi}")
        if not -90 <= self.elevation_limits_deg[0] < self.elevation_limits_deg[1] <= 90:
            raise ValueError("elevation_limits_deg must lie within [-90, 90]")
        return self


class _TurntableSection(_Strict):
    limits_deg: Limits


class _RigFile(_Strict):
    rig: _Header
    camera: _CameraSection
    gantry: _GantrySection
    turntable: _TurntableSection


@dataclass(frozen=True, eq=False)
class Gantry:
    """The reachable light sphere and its limits (radians inside, degrees in the file)."""

    centre: np.ndarray
    arm_radius: float
    azimuth_limits: tuple[float, float]
    elevation_limits: tuple[float, float]
    camera_keepout: float
    min_light_height: float


@dataclass(frozen=True, eq=False)
class Rig:
    name: str
    camera: Camera
    exposure_bracket_s: tuple[float, ...]
    gantry: Gantry
    turntable_limits_deg: tuple[float, float]
    source: str


def load_rig(path: str | Path) -> Rig:
    """Read and validate a rig file; errors name the file and the field."""
    path = Path(path)
    data = read_toml(path)
    check_header(data, path, RIG_FORMAT, {1}, header="rig")
    return _build(validate(_RigFile, data, path), str(path))


def sim_rig() -> Rig:
    """The built-in simulated rig (package data)."""
    ref = resources.files("hlr_lab.data") / SIM_RIG
    with resources.as_file(ref) as path:
        rig = load_rig(path)
    return Rig(
        rig.name, rig.camera, rig.exposure_bracket_s, rig.gantry, rig.turntable_limits_deg, "builtin:sim"
    )


def _build(f: _RigFile, source: str) -> Rig:
    c, g = f.camera, f.gantry
    camera = Camera.look_at(
        c.position_m,
        c.look_at_m,
        matrix=np.array(c.matrix),
        width=c.width,
        height=c.height,
        distortion=c.distortion,
        up=c.up,
    )
    gantry = Gantry(
        np.array(g.centre_m),
        g.arm_radius_m,
        tuple(np.radians(g.azimuth_limits_deg)),
        tuple(np.radians(g.elevation_limits_deg)),
        float(np.radians(g.camera_keepout_deg)),
        g.min_light_height_m,
    )
    return Rig(f.rig.name, camera, tuple(c.exposure_bracket_s), gantry, tuple(f.turntable.limits_deg), source)
