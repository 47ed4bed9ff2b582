"""The rig's devices, opened from the rig file: the Dynamixel gantry, the Modbus turntable, the lamp relay
and the camera.

The drivers' limits come from the rig's angle limits through the kinematics, so every goal is checked
twice: against the plan before the first move (:mod:`hlr_lab.instrument.motion`) and by the driver before sending.
:class:`RigDevices` always ends in a safe state: lamp off, turntable stopped, gantry torque off, each
read back from the device, and says (:class:`SafeState`) which steps it could not confirm.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial

from drivers.dynamixel import Axis, DynamixelGantry, GantryConfig
from drivers.errors import DeviceError
from drivers.modbus_stage import ModbusRelay, ModbusStage, StageConfig, StageMap
from drivers.net_camera import NetworkCamera
from drivers.opencv_camera import OpenCVCamera, OpenCVCameraConfig
from drivers.protocols import Camera, Clock
from drivers.retrying import retried
from hlr_lab.errors import InputError
from hlr_lab.rig.file import Rig
from hlr_lab.session.events import SafeStateLine, SafeStepLine

log = logging.getLogger(__name__)
HOLD_SETTLE_S = 5.0  # a gantry parked holding torque comes to rest within this after a stop
SAFE_STATE_ATTEMPTS = 3  # each Modbus safe-state step, on a fresh link each time (the servos: park())


def link(rig: Rig, field: str, override: str | None, advice: str) -> str:
    """Where a device is reached: ``override`` (the simulated rig's endpoint), else the rig file's
    ``field`` ("section.key"); neither is an error naming the field, with ``advice``."""
    section, key = field.split(".")
    address = override or getattr(getattr(rig.file, section), key)
    if not address:
        raise InputError(f"no {key}: {advice}", path=rig.source, field=field)
    return address


def gantry_config(rig: Rig, port: str | None = None) -> GantryConfig:
    """The gantry driver's settings; ``port`` overrides the file's (the simulated rig's pty)."""
    g = rig.file.gantry
    port = link(
        rig, "gantry.port", port, "give the servo adapter's device path (e.g. /dev/ttyUSB0) or a pyserial URL"
    )
    (az_lo, az_hi), (el_lo, el_hi) = rig.gantry.servo_limits
    azimuth, elevation = rig.gantry.servo_ids
    return GantryConfig(
        port,
        (Axis(azimuth, az_lo, az_hi, "azimuth"), Axis(elevation, el_lo, el_hi, "elevation")),
        baudrate=g.baudrate,
        profile_velocity=g.profile_velocity,
        profile_acceleration=g.profile_acceleration,
        tolerance_ticks=g.tolerance_ticks,
        settle_s=g.settle_s,
        reboot_on_alarm=g.reboot_on_alarm,
        reply_timeout_ms=g.reply_timeout_ms,
    )


def stage_config(rig: Rig, address: str | None = None) -> StageConfig:
    """The turntable driver's settings; ``address`` overrides the file's (the simulated rig's server)."""
    t = rig.file.turntable
    address = link(
        rig,
        "turntable.address",
        address,
        'give the drive\'s "host:port" (Modbus TCP) or its serial device path (RTU)',
    )
    lo, hi = sorted(rig.turntable_kinematics.steps_for(d) for d in rig.turntable_limits_deg)
    return StageConfig(
        address,
        lo,
        hi,
        map=replace(StageMap(), unit=t.device_id, **t.registers),
        baudrate=t.baudrate,
        speed=t.speed_steps_s,
        acceleration=t.acceleration_steps_s2,
        current=t.current_permille,
        tolerance_steps=t.tolerance_steps,
        reset_alarm=t.reset_alarm,
    )


@dataclass(frozen=True)
class SafeStep:
    """One step of the safe state: ``device`` ("lamp", "turntable", "gantry"), whether the device
    confirmed it, and what it confirmed (or why it could not)."""

    device: str
    ok: bool
    detail: str


@dataclass(frozen=True)
class SafeState:
    """What the safe state reached, device by device, as the devices themselves reported it."""

    steps: tuple[SafeStep, ...]

    @property
    def ok(self) -> bool:
        return all(step.ok for step in self.steps)

    def sentence(self) -> str:
        """One line for the operator: what was confirmed, or which steps failed and why."""
        if self.ok:
            return "; ".join(f"{s.device} {s.detail}" for s in self.steps)
        failed = [s for s in self.steps if not s.ok]
        done = [s.device for s in self.steps if s.ok]
        return (
            "NOT SAFE: "
            + "; ".join(f"{s.device}: {s.detail}" for s in failed)
            + (f" (confirmed safe: {', '.join(done)})" if done else "")
            + " — make the rig safe by hand (lamp power, drive and servo power)"
        )

    def as_event(self) -> SafeStateLine:
        """The journal's ``safe_state`` line."""
        steps = [SafeStepLine(device=s.device, ok=s.ok, detail=s.detail) for s in self.steps]
        return SafeStateLine(event="safe_state", ok=self.ok, steps=steps)


@dataclass
class RigDevices:
    """The opened devices; use as a context manager so that every exit leaves the rig safe. What the
    safe state reached is kept in :attr:`safe` once the block is left."""

    gantry: DynamixelGantry
    stage: ModbusStage
    lamp: ModbusRelay | None
    park: str = "torque_off"  # the rig file's gantry.park
    safe: SafeState | None = None

    def connect(self) -> dict[str, str]:
        """Configure and energise everything; returns a plain description of what answered."""
        self.stage.connect()
        models = self.gantry.connect()
        found = {self.stage.name: "ready"}
        found |= {f"servo {sid}": model for sid, model in models.items()}
        if self.lamp is not None:
            self.lamp.set(False)
            found[f"lamp relay (device {self.lamp.unit}, coil {self.lamp.coil})"] = "off"
        return found

    def safe_state(self) -> SafeState:
        """Lamp off, turntable stopped, gantry parked (torque off unless the rig says hold), links closed.
        Every step is tried whatever happened before, each is read back from the device, and the
        report says what was confirmed. The Modbus link is opened afresh first: the exchange that was
        running when the run stopped may have been cut short."""
        hold = self.park != "torque_off"
        try:
            self.stage.reconnect()
        except DeviceError as exc:
            log.error("%s", exc)  # every Modbus step below will fail and say so

        def park() -> str:
            if hold:  # hold where it is: stop, let it come to rest, then confirm it is not moving
                self.gantry.stop()
                self.gantry.wait_settled(HOLD_SETTLE_S)
            return self.gantry.park(torque_off=not hold)

        insist = partial(_on_fresh_links, self.stage)
        steps = [("lamp", insist(self.lamp.switch_off) if self.lamp else None),
                 ("turntable", insist(self.stage.halt)), ("gantry", park)]  # fmt: skip
        done = []
        for device, step in steps:
            if step is None:
                continue
            try:
                done.append(SafeStep(device, True, step()))
            except Exception as exc:
                problem = str(exc) if isinstance(exc, DeviceError) else f"{type(exc).__name__}: {exc}"
                log.error("safe state: %s: %s", device, problem)
                done.append(SafeStep(device, False, problem))
        self.gantry.release()
        self.stage.close()
        self.safe = SafeState(tuple(done))
        (log.info if self.safe.ok else log.error)("safe state: %s", self.safe.sentence())
        return self.safe

    def __enter__(self) -> RigDevices:
        return self

    def __exit__(self, *exc) -> None:
        self.safe_state()


def _on_fresh_links(stage: ModbusStage, step: Callable[[], str]) -> Callable[[], str]:
    """A Modbus safe-state step, tried again on a fresh link after a failure: the driver's own retries
    may all fall into one burst of faults, and a lamp left on is worth a second and a third try."""

    def fresh_link() -> None:
        with contextlib.suppress(DeviceError):
            stage.reconnect()

    def attempts() -> str:
        return retried(
            step,
            retries=SAFE_STATE_ATTEMPTS - 1,
            backoff_s=0.1,
            on=(DeviceError,),
            log=log,
            message="safe state: %s; trying again on a fresh link (%d of %d)",
            after_pause=fresh_link,
            journaled=False,  # the run is over: the safe-state lines are the log's
        )

    return attempts


@dataclass(frozen=True)
class CameraKind:
    """One kind of camera a rig file can describe: the ``[camera]`` key that says so, the link it is
    reached on (what the device lock holds; None: not given), and how it is opened (``endpoint``: the
    simulated rig's frame endpoint, which replaces the file's)."""

    key: str
    link: Callable[[Rig], str | None]
    open: Callable[[Rig, str | None], Camera]


def _network_camera(rig: Rig, endpoint: str | None) -> Camera:
    address = link(rig, "camera.address", endpoint, 'set it to the camera\'s frame endpoint ("host:port"), or '
                   "describe an OpenCV camera in [camera.capture]")  # fmt: skip
    return NetworkCamera(address, reply_timeout_s=rig.file.camera.reply_timeout_s)


def _opencv_camera(rig: Rig, endpoint: str | None) -> Camera:
    capture = rig.file.camera.capture
    assert capture is not None  # camera_kind chose this kind for it
    c = capture.model_dump()
    return OpenCVCamera(OpenCVCameraConfig(**{**c, "exposure_range_s": tuple(c["exposure_range_s"])}))


def _genicam_camera(rig: Rig, endpoint: str | None) -> Camera:
    from drivers.genicam_camera import GenICamCamera, GenICamConfig  # Aravis: only when such a camera opens

    g = rig.file.camera.genicam
    if g is None:  # the simulated rig's GigE Vision camera (camera_kind chose it by its address): defaults
        assert endpoint is not None
        return GenICamCamera(GenICamConfig(endpoint, frame_timeout_s=rig.file.camera.reply_timeout_s))
    return GenICamCamera(GenICamConfig(**{**g.model_dump(), "device": endpoint or g.device}))


# the one table of camera kinds: a rig file names one by its key in [camera] (a frame endpoint by default)
CAMERA_KINDS = {
    "genicam": CameraKind("genicam", lambda rig: g.device if (g := rig.file.camera.genicam) else None, _genicam_camera),
    "network": CameraKind("address", lambda rig: rig.file.camera.address, _network_camera),
    "opencv": CameraKind("capture", lambda rig: c.device if (c := rig.file.camera.capture) else None, _opencv_camera),
}  # fmt: skip


def camera_kind(rig: Rig, endpoint: str | None = None) -> str:
    """Which of :data:`CAMERA_KINDS` ``rig``'s camera is. A simulated rig's ``endpoint`` says it: a bare
    address (127.0.0.N) is a GigE Vision camera, a "host:port" a frame endpoint."""
    if endpoint is None:
        for name, kind in CAMERA_KINDS.items():
            if getattr(rig.file.camera, kind.key) is not None:
                return name
        return "network"
    return "network" if ":" in endpoint else "genicam"


def open_camera(rig: Rig, endpoint: str | None = None) -> Camera:
    """The rig's camera, as its kind (:data:`CAMERA_KINDS`) opens it; ``endpoint``: the simulated rig's."""
    return CAMERA_KINDS[camera_kind(rig, endpoint)].open(rig, endpoint)


def open_devices(rig: Rig, *, gantry_port: str | None = None, stage_address: str | None = None) -> RigDevices:
    """Open the links (nothing moves yet: :meth:`RigDevices.connect` configures and energises)."""
    stage = ModbusStage(stage_config(rig, stage_address))
    try:
        gantry = DynamixelGantry(gantry_config(rig, gantry_port))
    except BaseException:
        stage.close()
        raise
    lamp_file = rig.file.lamp
    lamp = None if lamp_file is None else ModbusRelay(stage, lamp_file.device_id, lamp_file.coil)
    return RigDevices(gantry, stage, lamp, rig.file.gantry.park)


@dataclass(frozen=True)
class Links:
    """Where the devices are reached when not where the rig file says (the simulated rig's endpoints),
    and the rig's clock when it is not the wall's (a simulated world's)."""

    gantry: str | None = None
    stage: str | None = None
    camera: str | None = None
    clock: Clock | None = None


def rig_device_links(rig: Rig, links: Links) -> list[tuple[str, str]]:
    """(description, link) of every device a run on ``rig`` uses, for :func:`hlr_lab.instrument.locks.hold_devices`;
    the camera as :func:`hlr_lab.instrument.devices.open_camera` chooses it."""
    f = rig.file
    camera = links.camera or CAMERA_KINDS[camera_kind(rig)].link(rig)
    found = [
        ("the gantry's servo bus", links.gantry or f.gantry.port),
        ("the turntable's Modbus link", links.stage or f.turntable.address),
        ("the camera", camera),
    ]
    return [(what, str(link)) for what, link in found if link]
