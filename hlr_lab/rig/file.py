"""The rig's geometry, as planning needs it: camera, light gantry sphere and limits, turntable limits.

Read from ``rig.toml`` (docs/rig.example.toml explains every field); the simulated rig ships as package
data (``--sim``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from drivers.dynamixel import SDK_REPLY_TIMEOUT_MS
from drivers.modbus_stage import StageMap
from hlr_lab.files import OpenModel, StrictModel, as_pair, as_triple, check_header, read_toml, validate
from hlr_lab.geometry.camera import Camera
from hlr_lab.rig.kinematics import GantryKinematics, TurntableKinematics

RIG_FORMAT = "hlr-lab.rig"
SIM_RIG = "sim-rig.toml"

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
_PAIR = Field(min_length=2, max_length=2)
Limits = Annotated[list[float], _PAIR]
ServoId = Annotated[int, Field(ge=0, le=252)]  # Protocol 2.0 unicast IDs
# what an X-series servo's Baud Rate (address 8) can be set to (the ROBOTIS e-manual)
DYNAMIXEL_BAUD_RATES = (9600, 57600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000)
# OpenCV's predefined ArUco dictionaries and how many markers each has (cv2.aruco.getPredefinedDictionary)
ARUCO_DICTIONARIES = {
    **{f"DICT_{n}X{n}_{size}": size for n in (4, 5, 6, 7) for size in (50, 100, 250, 1000)},
    "DICT_ARUCO_ORIGINAL": 1024,
    "DICT_APRILTAG_16h5": 30,
    "DICT_APRILTAG_25h9": 35,
    "DICT_APRILTAG_36h10": 2320,
    "DICT_APRILTAG_36h11": 587,
    "DICT_ARUCO_MIP_36h12": 250,
}


class _Header(StrictModel):
    format: Literal["hlr-lab.rig"]
    version: Literal[1]
    name: str = "rig"


class _CaptureSection(StrictModel):
    """A camera driven through OpenCV (drivers.opencv_camera): V4L2/UVC, manual exposure and gain."""

    device: str  # "/dev/video0" or a camera index
    backend: Literal["v4l2", "images", "any"] = "v4l2"
    fourcc: Annotated[str, Field(min_length=4, max_length=4)] | None = None  # e.g. "Y16 "
    bits: Literal[8, 10, 12, 16] = 8
    msb_aligned: bool = False
    exposure_unit_s: float = Field(default=1e-4, gt=0)
    exposure_range_s: Annotated[list[Annotated[float, Field(gt=0)]], _PAIR] = [1e-4, 10.0]
    manual_exposure: float = 1.0
    gain_per_db: float = Field(default=1.0, gt=0)
    max_gain_db: float = Field(default=24.0, ge=0)
    stale_frames: int = Field(default=2, ge=0)


class _GenICamSection(StrictModel):
    """A machine-vision camera through Aravis (drivers.genicam_camera): GigE Vision or USB3 Vision."""

    device: str = Field(min_length=1)  # Aravis's id ("Basler-21234567", as arv-tool-0.8 lists it) or IP
    pixel_format: str | None = None  # a PFNC name it offers (Mono12p, BayerRG12, RGB12, …); None: its own
    features: dict[str, bool | int | float | str] = {}  # set as the camera opens, in this order
    frame_timeout_s: float = Field(default=20.0, gt=0, le=3600)
    packet_size: int | None = Field(default=None, ge=576, le=65535)  # GigE Vision; None: negotiated
    gain_raw_per_db: float | None = Field(default=None, gt=0)  # a camera with GainRaw instead of Gain
    max_gain_db: float = Field(default=24.0, ge=0)

    @field_validator("pixel_format")
    @classmethod
    def _a_decoded_format(cls, name: str | None) -> str | None:
        from drivers.pfnc import FORMATS

        if name is not None and name not in FORMATS:
            raise ValueError(
                f"{name!r} is not a pixel format hlr-lab decodes; use one of {', '.join(sorted(FORMATS))}"
            )
        return name


class _CameraSection(StrictModel):
    width: int = Field(gt=0, le=65535)
    height: int = Field(gt=0, le=65535)
    matrix: Annotated[list[Vec3], Field(min_length=3, max_length=3)]
    distortion: Annotated[list[float], Field(max_length=5)] = []
    position_m: Vec3
    look_at_m: Vec3
    up: Vec3 = [0.0, 0.0, 1.0]
    # rotation of the camera about its optical axis after look_at_m/up, right-handed about its +z
    roll_deg: float = Field(default=0.0, ge=-180, le=180)
    exposure_bracket_s: Annotated[list[Annotated[float, Field(gt=0, le=3600)]], Field(min_length=1)] = [0.01]
    # how frames are taken: [camera.genicam] for a machine-vision camera (Aravis), [camera.capture] for
    # one driven through OpenCV, or a frame endpoint "host:port" (drivers.net_camera); the simulated rig
    # supplies its own camera
    address: str | None = None
    capture: _CaptureSection | None = None
    genicam: _GenICamSection | None = None
    # a frame that has not arrived this long after its exposure ends is a camera that stopped answering
    reply_timeout_s: float = Field(default=20.0, gt=0, le=3600)

    @model_validator(mode="after")
    def _a_view(self):
        view, up = np.subtract(self.look_at_m, self.position_m), np.asarray(self.up, np.float64)
        if np.linalg.norm(view) < 1e-3:
            raise ValueError(
                "look_at_m is where the camera is (position_m): give the point the camera looks at"
            )
        if (
            np.linalg.norm(up) == 0
            or np.linalg.norm(np.cross(view / np.linalg.norm(view), up / np.linalg.norm(up))) < 1e-3
        ):
            raise ValueError(
                "the camera looks along up (position_m → look_at_m is parallel to up), so its image has no up: "
                "give up a direction across the view (e.g. up = [0.0, 1.0, 0.0] for a camera looking down)"
            )
        return self

    @model_validator(mode="after")
    def _a_pinhole_matrix(self):
        (fx, skew, cx), (zero, fy, cy), last = self.matrix
        # OpenCV's camera model, which calibration fits and its functions use: no skew
        if not (fx > 0 and fy > 0 and skew == 0 and zero == 0 and last == [0.0, 0.0, 1.0]):
            raise ValueError(
                "matrix must be a camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with focal lengths fx, fy "
                "> 0 (pixels); hlr-lab calibrate camera measures it"
            )
        if not (0 <= cx <= self.width and 0 <= cy <= self.height):
            raise ValueError(
                f"matrix: the principal point ({cx:g}, {cy:g}) lies outside the {self.width} × {self.height} "
                "image; check width, height and the matrix (cx, cy are in pixels)"
            )
        return self

    @field_validator("address")
    @classmethod
    def _a_frame_endpoint(cls, address: str | None) -> str | None:
        return address if address is None else _host_port(address)

    @model_validator(mode="after")
    def _one_way_to_the_camera(self):
        given = [name for name in ("address", "capture", "genicam") if getattr(self, name)]
        if len(given) > 1:
            raise ValueError(
                f"give one way to the camera, not {' and '.join(given)}: [camera.genicam] (a GenICam camera), "
                "[camera.capture] (OpenCV) or address (a frame endpoint)"
            )
        return self


class _GantrySection(StrictModel):
    centre_m: Vec3
    arm_radius_m: float = Field(gt=0)
    azimuth_limits_deg: Limits
    elevation_limits_deg: Limits
    camera_keepout_deg: float = Field(ge=0, lt=90)
    min_light_height_m: float = 0.0
    # tick ↔ angle mapping (docs/conventions.md): servo readings at 0°, and whether ticks grow with the angle
    servo_ids: Annotated[list[ServoId], _PAIR] = [1, 2]
    zero_ticks: Annotated[list[int], _PAIR] = [2048, 1024]
    directions: Annotated[list[Literal[-1, 1]], _PAIR] = [1, 1]
    ticks_per_rev: int = Field(default=4096, gt=0)
    # direction of the azimuth axis in the world frame (calibrated; +z on a rig built to its drawing):
    # azimuth 0 is world +x projected onto the plane perpendicular to it, elevation is measured from
    # that plane (hlr_lab.rig.kinematics)
    azimuth_axis: Vec3 = [0.0, 0.0, 1.0]
    # the link: a device path or a pyserial URL; the simulated rig supplies its own pty
    port: str | None = None
    baudrate: int = 1_000_000
    # the servo's Profile Velocity and Acceleration (the e-manual's range: 0–32767; 0 would mean "unlimited")
    profile_velocity: int = Field(default=100, gt=0, le=32767)  # 0.229 rev/min per unit
    profile_acceleration: int = Field(default=20, gt=0, le=32767)  # 214.6 rev/min² per unit
    tolerance_ticks: int = Field(default=2, ge=0)
    settle_s: float = Field(default=0.05, ge=0)
    reboot_on_alarm: bool = False  # clear a hardware error by reboot only when the operator allows it
    # the wait for a servo's reply beyond its bytes' time: the SDK's 2 × 16 + 2 ms (an FTDI adapter's
    # default latency timer, twice); less once the adapter's timer is 1 ms, more behind a slow link
    reply_timeout_ms: float = Field(default=SDK_REPLY_TIMEOUT_MS, gt=0, le=10_000)
    # at the end of a run or on a stop: "torque_off" (the arm can be moved by hand; a heavy arm may sag)
    # or "hold" (the servos keep the last position, powered)
    park: Literal["torque_off", "hold"] = "torque_off"

    @field_validator("baudrate")
    @classmethod
    def _a_servo_baud_rate(cls, baudrate: int) -> int:
        if baudrate not in DYNAMIXEL_BAUD_RATES:
            raise ValueError(
                f"{baudrate} bps is not a speed an X-series servo can be set to; use one of "
                f"{', '.join(map(str, DYNAMIXEL_BAUD_RATES))} (the servos' Baud Rate)"
            )
        return baudrate

    @model_validator(mode="after")
    def _ordered(self):
        for name in ("azimuth_limits_deg", "elevation_limits_deg"):
            _ordered_limits(name, getattr(self, name))
        if not -90 <= self.elevation_limits_deg[0] < self.elevation_limits_deg[1] <= 90:
            raise ValueError("elevation_limits_deg must lie within [-90, 90]")
        a = np.asarray(self.azimuth_axis, float)
        if not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-6 or np.linalg.norm(a[1:]) < 1e-6:
            raise ValueError("azimuth_axis must be a direction (not zero, not along x), e.g. [0, 0, 1]")
        if self.servo_ids[0] == self.servo_ids[1]:
            raise ValueError("servo_ids: azimuth and elevation need two different servo IDs")
        self._limits_fit_the_servos()
        return self

    def kinematics(self) -> GantryKinematics:
        return GantryKinematics(
            np.array(self.centre_m),
            self.arm_radius_m,
            as_pair(self.zero_ticks),
            as_pair(self.directions),
            self.ticks_per_rev,
            as_triple(self.azimuth_axis),
        )

    def _limits_fit_the_servos(self) -> None:
        spans = self.kinematics().tick_span(
            as_pair(self.azimuth_limits_deg), as_pair(self.elevation_limits_deg)
        )
        # one tick of slack: a closed full circle [−180°, 180°] needs ticks_per_rev + 1 positions
        for name, (lo, hi) in zip(("azimuth_limits_deg", "elevation_limits_deg"), spans, strict=True):
            if lo < -1 or hi > self.ticks_per_rev:
                raise ValueError(
                    f"{name} map to servo ticks [{lo}, {hi}], beyond the servo's one turn "
                    f"0…{self.ticks_per_rev - 1}; set zero_ticks so that the limits fit, or narrow them"
                )


class _TurntableSection(StrictModel):
    limits_deg: Limits
    steps_per_degree: float = Field(default=100.0, gt=0)
    zero_steps: int = 0  # stage position at 0°
    # the link: "host:port" (Modbus TCP) or a serial device path (RTU); the simulated rig supplies its own
    address: str | None = None
    device_id: int = Field(default=1, ge=1, le=247)
    baudrate: int = Field(default=115_200, gt=0)
    speed_steps_s: int = Field(default=4000, gt=0)
    acceleration_steps_s2: int = Field(default=8000, gt=0)
    current_permille: int = Field(default=500, gt=0, le=1000)
    tolerance_steps: int = Field(default=1, ge=0)
    reset_alarm: bool = False  # reset a drive alarm only when the operator allows it
    # overrides of the AZ driver's register map (drivers.modbus_stage.StageMap), by field name
    registers: dict[str, int] = {}

    @model_validator(mode="after")
    def _ordered(self):
        _ordered_limits("limits_deg", self.limits_deg)
        return self

    @field_validator("address")
    @classmethod
    def _a_modbus_link(cls, address: str | None) -> str | None:
        if address is None or address.startswith(("/", "COM")):  # a serial device: drivers.modbus_stage
            return address
        return _host_port(address, ", nor a serial device path (/dev/…, COMn)")

    @field_validator("registers")
    @classmethod
    def _known_registers(cls, registers: dict[str, int]) -> dict[str, int]:
        known = {f.name for f in fields(StageMap)} - {"unit"}
        unknown = sorted(set(registers) - known)
        if unknown:
            raise ValueError(f"unknown register names {unknown}; known: {sorted(known)}")
        return registers


def _host_port(address: str, otherwise: str = "") -> str:
    """A network endpoint "host:port" (or "tcp://host:port"), checked before a driver tries it;
    ``otherwise`` names what else the field may be, for the message."""
    host, _, port = address.removeprefix("tcp://").rpartition(":")
    if not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{address!r} is not host:port (e.g. 192.168.0.30:502, a port 1–65535){otherwise}")
    return address


def _ordered_limits(name: str, limits: list[float]) -> None:
    lo, hi = limits
    if lo >= hi:
        raise ValueError(f"{name}: the lower limit {lo:g} must come first and be below the upper {hi:g}")


class _LampSection(StrictModel):
    """The lamp relay: a coil of a Modbus module on the turntable's link."""

    device_id: int = Field(default=2, ge=1, le=247)
    coil: int = Field(default=0, ge=0)


class _LightSection(StrictModel):
    """The lamp as a light source (docs/conventions.md): irradiance Φ/d² at distance d for a point light; a
    directional light (a distant lamp) shines from the lamp's direction seen from the gantry centre with
    irradiance Φ."""

    type: Literal["point", "directional"] = "point"
    power: float = Field(default=1.0, gt=0)  # Φ, in the unit the fitted reflectances are relative to
    drift: _DriftSection | None = None  # a simulated world's lamp (true rig files); hlr-lab measures its own


class _DriftSection(StrictModel):
    """How a simulated world's lamp drifts (``--true-rig`` files; see sim/lamp.py). A real rig's lamp is
    not described: hlr-lab measures it."""

    warm_up: float = Field(default=0.0, ge=-0.5, le=0.5)
    warm_up_s: float = Field(default=1.0, gt=0)
    per_hour: float = Field(default=0.0, ge=-0.5, le=0.5)
    flicker: float = Field(default=0.0, ge=0, le=0.1)


class _SensorSection(StrictModel):
    """The camera's radiometric response: linear, DN = sensitivity · radiance · t · gain + black level."""

    sensitivity: float = Field(default=4095.0, gt=0)  # DN per (radiance unit · second) at 0 dB
    black_level_dn: float = Field(default=0.0, ge=0)
    read_noise_dn: float = Field(default=1.5, ge=0)  # below a few of these a value is dark-noise dominated
    conversion_gain_dn_per_e: float | None = Field(default=None, gt=0)  # photon noise: var = gain · signal


class _BoardSection(StrictModel):
    """The ChArUco board of ``hlr-lab calibrate camera`` (OpenCV's conventions) and how it stands."""

    squares: Annotated[list[Annotated[int, Field(ge=3, le=100)]], _PAIR]  # across, down
    square_m: float = Field(gt=0, le=1)
    marker_m: float = Field(gt=0, le=1)
    dictionary: str = "DICT_4X4_50"  # OpenCV's name of the ArUco dictionary (ARUCO_DICTIONARIES)
    centre_height_m: float = Field(ge=0, le=2)  # the board's centre above the plate, on its first wedge face

    @model_validator(mode="after")
    def _marker_inside(self):
        if self.marker_m >= self.square_m:
            raise ValueError("marker_m must be smaller than square_m (the marker sits inside a square)")
        if self.dictionary not in ARUCO_DICTIONARIES:
            raise ValueError(
                f"dictionary {self.dictionary!r} is not one of OpenCV's ArUco dictionaries "
                f"({', '.join(ARUCO_DICTIONARIES)}); give the one the board was printed with"
            )
        markers = self.squares[0] * self.squares[1] // 2  # a ChArUco board has a marker in every other square
        if markers > ARUCO_DICTIONARIES[self.dictionary]:
            raise ValueError(
                f"a {self.squares[0]} × {self.squares[1]} board has {markers} markers, more than "
                f"{self.dictionary}'s {ARUCO_DICTIONARIES[self.dictionary]}; give the dictionary it was printed with"
            )
        return self


class _MirrorBallSection(StrictModel):
    """The polished ball of ``hlr-lab calibrate gantry``, resting on the plate."""

    radius_m: float = Field(gt=0, le=0.2)
    place_m: Annotated[list[float], _PAIR]  # where it rests on the plate at turntable 0° (x, y), roughly


class _WhiteReferenceSection(StrictModel):
    """The white reference of ``hlr-lab calibrate radiometric``: a flat Lambertian square lying on the
    plate (and, with ``run_place_m``, beside the object during runs)."""

    reflectance: Vec3 = [0.99, 0.99, 0.99]  # per channel (linear RGB), from its certificate
    reflectance_se: float = Field(default=0.0, ge=0, le=0.5)  # the certificate's uncertainty, relative
    size_m: float = Field(default=0.1, gt=0, le=0.5)  # the square's side
    place_m: Annotated[list[float], _PAIR] = [0.0, 0.0]  # its centre on the plate at turntable 0° (x, y)
    thickness_m: float = Field(default=0.0, ge=0, le=0.05)  # its face above the plate
    # where it lies beside the object during runs (turntable 0°): acquire measures the lamp on it in every
    # pose (hlr_lab.acquisition.white_reference); absent: it is not there during runs
    run_place_m: Annotated[list[float], _PAIR] | None = None

    @field_validator("reflectance")
    @classmethod
    def _a_reflectance(cls, v):
        if not all(0 < r <= 1 for r in v):
            raise ValueError("each channel's reflectance lies in (0, 1]")
        return v


# the camera's parameters as [calibration.camera] covariance orders them (those of the calibration's
# joint fit; hlr_lab.reflectance.systematic moves the camera by them): a turn ω applied to its rotation
# (R' = exp(ω)·R, rad) with its translation t held (x_c = R x_w + t, m: a turn about the world's origin),
# t itself, the intrinsics (px) and the distortion k1 k2 p1 p2
CAMERA_PARAMETERS = ("rotation_x_rad", "rotation_y_rad", "rotation_z_rad", "translation_x_m", "translation_y_m",
                     "translation_z_m", "fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2")  # fmt: skip
# the gantry's, as [calibration.gantry] covariance orders them (the mirror-ball fit's own)
GANTRY_PARAMETERS = ("centre_x_m", "centre_y_m", "centre_z_m", "arm_radius_m", "axis_x", "axis_y",
                     "zero_az_ticks", "zero_el_ticks")  # fmt: skip

# the field of each calibration record that the materials' systematic uncertainty needs (docs/fitting.md;
# a record written before it was kept lacks it: hlr-lab doctor says so)
SYSTEMATIC_FIELDS = {"camera": "covariance", "gantry": "covariance", "radiometric": "sensitivity_se_rel"}


class _Provenance(OpenModel):
    """What a calibration procedure recorded: when, with what, how well (free-form beyond these)."""

    date: str
    hlr_lab: str


class _CalibrationSection(StrictModel):
    board: _BoardSection | None = None
    mirror_ball: _MirrorBallSection | None = None
    white_reference: _WhiteReferenceSection | None = None
    camera: _Provenance | None = None  # written by hlr-lab calibrate camera
    gantry: _Provenance | None = None
    radiometric: _Provenance | None = None


class RigFile(StrictModel):
    """``rig.toml`` as written (docs/rig.example.toml explains every field): strict types, no unknown
    key, each section checked where it is read. :func:`load_rig` turns it into a :class:`Rig`."""

    rig: _Header
    camera: _CameraSection
    gantry: _GantrySection
    turntable: _TurntableSection
    lamp: _LampSection | None = None
    light: _LightSection = _LightSection()
    sensor: _SensorSection = _SensorSection()
    calibration: _CalibrationSection = _CalibrationSection()


@dataclass(frozen=True, eq=False)
class Gantry:
    """The reachable light sphere and its limits (radians inside, degrees in the file)."""

    centre: np.ndarray
    arm_radius: float
    azimuth_limits: tuple[float, float]
    elevation_limits: tuple[float, float]
    camera_keepout: float
    min_light_height: float
    kinematics: GantryKinematics
    servo_ids: tuple[int, int]  # azimuth, elevation
    servo_limits: tuple[tuple[int, int], tuple[int, int]]  # (min, max) ticks, azimuth and elevation


@dataclass(frozen=True, eq=False)
class Rig:
    """The rig as planning, acquisition and fitting use it, built from a validated :class:`RigFile`.

    Attributes
    ----------
    camera
        The camera model: intrinsics, distortion and pose in the world frame (metres).
    exposure_bracket_s
        The exposures of one pose, seconds, longest first.
    gantry
        The reachable light sphere: centre and arm radius (m), angle limits (radians), the keep-out cone
        about the camera, the servo kinematics and tick limits.
    turntable_limits_deg
        (lowest, highest) turntable angle, degrees.
    turntable_kinematics
        Degrees ↔ stage steps.
    source
        The rig file's path (or ``builtin:…``), for messages.
    file
        The validated file itself, for the device links (:mod:`hlr_lab.instrument.devices`).
    """

    name: str
    camera: Camera
    exposure_bracket_s: tuple[float, ...]
    gantry: Gantry
    turntable_limits_deg: tuple[float, float]
    turntable_kinematics: TurntableKinematics
    source: str
    file: RigFile  # the validated file, for the device links (hlr_lab.instrument.devices)


def load_rig(path: str | Path) -> Rig:
    """Read and validate a rig file; errors name the file and the field."""
    path = Path(path)
    data = read_toml(path)
    check_header(data, path, RIG_FORMAT, {1}, header="rig")
    return _build(validate(RigFile, data, path), str(path))


def rig_of_snapshot(snapshot: dict, source: str) -> Rig:
    """The rig recorded in a session (``session.json``), validated as a rig file is."""
    return _build(validate(RigFile, snapshot, Path(source)), source)


def rig_source_path(rig: Rig) -> Path:
    """The file ``rig`` was read from (the built-in simulated rig's inside the installed package: read it,
    never write beside it)."""
    if rig.source == "builtin:sim":
        with resources.as_file(resources.files("hlr_lab.data") / SIM_RIG) as path:
            return Path(path)
    return Path(rig.source)


def sim_rig() -> Rig:
    """The built-in simulated rig (package data)."""
    ref = resources.files("hlr_lab.data") / SIM_RIG
    with resources.as_file(ref) as path:
        rig = load_rig(path)
    return replace(rig, source="builtin:sim")


def _build(f: RigFile, source: str) -> Rig:
    c, g = f.camera, f.gantry
    kinematics = g.kinematics()
    camera = Camera.look_at(
        c.position_m,
        c.look_at_m,
        matrix=np.array(c.matrix),
        width=c.width,
        height=c.height,
        distortion=c.distortion,
        up=c.up,
        roll_deg=c.roll_deg,
    )
    gantry = Gantry(
        np.array(g.centre_m),
        g.arm_radius_m,
        as_pair([float(a) for a in np.radians(g.azimuth_limits_deg)]),
        as_pair([float(a) for a in np.radians(g.elevation_limits_deg)]),
        float(np.radians(g.camera_keepout_deg)),
        g.min_light_height_m,
        kinematics,
        as_pair(g.servo_ids),
        kinematics.servo_limits(as_pair(g.azimuth_limits_deg), as_pair(g.elevation_limits_deg)),
    )
    t = f.turntable
    return Rig(
        f.rig.name,
        camera,
        tuple(c.exposure_bracket_s),
        gantry,
        as_pair(t.limits_deg),
        TurntableKinematics(t.steps_per_degree, t.zero_steps),
        source,
        f,
    )
