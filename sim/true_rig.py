"""The world as it really is: a rig file read by the simulator itself.

hlr-lab believes one rig file (the drawing, or its calibration); the simulated world can be built from
another, the *true* rig (``--true-rig``), so that calibration has something to find. The simulator
reads it in its own words — its own TOML reading, camera pose and gantry kinematics, no code shared
with hlr-lab — so that it stays an independent truth. Only what shapes the world is read: the
camera's intrinsics and pose, the gantry's geometry and tick mapping, the turntable's step mapping,
the sensor's response and noise (``[sensor]``), the lamp's power and drift (``[light]``), and a white
reference lying beside the object during runs (``[calibration.white_reference]`` with ``run_place_m``).

Built-in true rigs live in ``sim/data`` (``builtin:bench-offsets``: geometry off its drawing;
``builtin:bench-night``: the same bench, its sensor and lamp off their nominal values too, and a lamp
that drifts).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from sim.camera import GantryGeometry, StageGeometry
from sim.lamp import LampModel
from sim.render.camera import CameraSpec
from sim.render.scene import Patch
from sim.render.sensor import SensorModel
from sim.tuples import pair, triple

BUILTIN = "builtin:"


class TrueRigError(ValueError):
    """A true rig file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class TrueRig:
    camera: CameraSpec
    gantry: GantryGeometry
    stage: StageGeometry
    servo_ids: tuple[int, int]  # azimuth, elevation
    source: str
    sensor: SensorModel = field(default_factory=SensorModel)  # [sensor]: what the camera's pixels really do
    lamp: LampModel = field(default_factory=LampModel)  # [light] power and drift: what the lamp really gives
    run_reference: Patch | None = None  # a white reference on the plate beside the object during runs


def builtin_true_rigs() -> list[str]:
    return sorted(f"{BUILTIN}{p.name.removesuffix('.toml')}" for p in resources.files("sim.data").iterdir()
                  if p.name.endswith(".toml"))  # fmt: skip


def true_rig_text(spec: str | Path) -> str:
    """The text of a true rig file (path) or of a built-in one (``builtin:NAME``)."""
    spec = str(spec)
    if spec.startswith(BUILTIN):
        name = spec.removeprefix(BUILTIN)
        ref = resources.files("sim.data") / f"{name}.toml"
        if not ref.is_file():
            raise TrueRigError(f"{spec}: no such built-in true rig; known: {', '.join(builtin_true_rigs())}")
        return ref.read_text(encoding="utf-8")
    try:
        return Path(spec).read_text(encoding="utf-8")
    except OSError as exc:
        raise TrueRigError(f"{spec}: cannot read the true rig file ({exc.strerror})") from exc


def load_true_rig(spec: str | Path) -> TrueRig:
    """A rig file (path) or a built-in true rig (``builtin:NAME``) → the world's geometry."""
    spec = str(spec)
    text = true_rig_text(spec)
    try:
        data = tomllib.loads(text)
        return _world(data, spec)
    except tomllib.TOMLDecodeError as exc:
        raise TrueRigError(f"{spec}: not valid TOML ({exc})") from exc
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, TrueRigError):
            raise
        raise TrueRigError(
            f"{spec}: {exc!r} in the camera, gantry, turntable, sensor or light section"
        ) from exc


def _world(data: dict, source: str) -> TrueRig:
    c, g, t = data["camera"], data["gantry"], data["turntable"]
    ids = pair(int(i) for i in g.get("servo_ids", (1, 2)))
    gantry = GantryGeometry(
        centre=triple(float(v) for v in g["centre_m"]),
        arm_radius=float(g["arm_radius_m"]),
        azimuth_servo=ids[0],
        elevation_servo=ids[1],
        zero_ticks=pair(int(v) for v in g.get("zero_ticks", (2048, 1024))),
        ticks_per_rev=int(g.get("ticks_per_rev", 4096)),
        directions=pair(int(v) for v in g.get("directions", (1, 1))),
        azimuth_axis=triple(float(v) for v in g.get("azimuth_axis", (0.0, 0.0, 1.0))),
    )
    stage = StageGeometry(float(t["steps_per_degree"]), int(t.get("zero_steps", 0)))
    return TrueRig(_camera(c), gantry, stage, ids, source, _sensor(data.get("sensor", {})),
                   _lamp(data.get("light", {})), _run_reference(data.get("calibration", {})))  # fmt: skip


def _run_reference(calibration: dict) -> Patch | None:
    """The white reference where it lies during runs (``run_place_m``), if it stays on the plate then."""
    w = calibration.get("white_reference", {})
    if "run_place_m" not in w:
        return None
    x, y = (float(v) for v in w["run_place_m"])
    return Patch((x, y), float(w.get("size_m", 0.1)), float(w.get("thickness_m", 0.0)),
                 triple(float(r) for r in w.get("reflectance", (0.99, 0.99, 0.99))))  # fmt: skip


def _sensor(s: dict) -> SensorModel:
    """[sensor] as the simulator takes it: sensitivity (DN per radiance · s), black level and read noise
    (DN), conversion gain (DN per electron: sets the photon noise)."""
    d = SensorModel()
    assert d.electrons_per_dn is not None  # the default sensor has photon noise
    gain = float(s.get("conversion_gain_dn_per_e", 1.0 / d.electrons_per_dn))
    if not (gain > 0 and float(s.get("sensitivity", d.sensitivity)) > 0):
        raise ValueError("sensitivity and conversion_gain_dn_per_e must be positive")
    return SensorModel(
        sensitivity=float(s.get("sensitivity", d.sensitivity)),
        electrons_per_dn=1.0 / gain,
        read_noise_dn=float(s.get("read_noise_dn", d.read_noise_dn)),
        black_level_dn=float(s.get("black_level_dn", d.black_level_dn)),
    )


def _lamp(light: dict) -> LampModel:
    """[light] power and drift (:mod:`sim.lamp`). The scene's own power stays the unit: the world's lamp
    gives ``power`` times it."""
    drift = light.get("drift", {})
    unknown = set(drift) - {"warm_up", "warm_up_s", "per_hour", "flicker"}
    if unknown:
        raise ValueError(f"[light] drift: unknown keys {sorted(unknown)}")
    return LampModel(float(light.get("power", 1.0)), **{k: float(v) for k, v in drift.items()})


def _camera(c: dict) -> CameraSpec:
    """OpenCV pose from where the camera stands, what it looks at, which way is up and its roll."""
    eye, target = np.asarray(c["position_m"], float), np.asarray(c["look_at_m"], float)
    up = np.asarray(c.get("up", (0.0, 0.0, 1.0)), float)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    roll = np.radians(float(c.get("roll_deg", 0.0)))  # the body turned about its optical axis
    right, down = np.cos(roll) * right + np.sin(roll) * down, np.cos(roll) * down - np.sin(roll) * right
    rotation = np.stack([right, down, forward])
    matrix = np.asarray(c["matrix"], float)
    if matrix.shape != (3, 3) or not (matrix[0, 0] > 0 and matrix[1, 1] > 0) or matrix[0, 1] != 0:
        raise ValueError("[camera] matrix: a 3 × 3 [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    distortion = np.zeros(5)
    given = np.asarray(c.get("distortion", []), float)
    distortion[: len(given)] = given
    return CameraSpec(
        matrix,
        distortion,
        rotation,
        -rotation @ eye,
        int(c["width"]),
        int(c["height"]),
    )
