"""``hlr-lab doctor``: connect to every device of a rig, read what it says about itself, and say in plain
words what is wrong and what to do.

Read-only: nothing is configured, energised or moved, so it is safe to run on a rig in any state (but
not beside a run: it takes the same device locks, :mod:`hlr_lab.instrument.locks`). The
diagnoses are pure functions of the devices' reports, so each rule is tested without a fault to stage.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from typing import Literal

from drivers.dynamixel import DynamixelGantry, ServoReport
from drivers.errors import DeviceTimeout, HlrLabError
from drivers.modbus_stage import DriveReport, ModbusRelay, ModbusStage, StageConfig
from hlr_lab.instrument.devices import Links, gantry_config, open_camera, rig_device_links, stage_config
from hlr_lab.instrument.locks import Busy, hold_devices
from hlr_lab.rig.file import SYSTEMATIC_FIELDS, Rig
from hlr_lab.rig.kinematics import TurntableKinematics

Level = Literal["ok", "warning", "problem"]
HOT_MARGIN_C = 10  # warn this close to the servo's own temperature limit (it shuts down at the limit)


@dataclass(frozen=True)
class Finding:
    """One line of ``doctor``'s table: the device, how it is (ok, warning, problem), what it says and what to do."""

    device: str
    level: Level
    message: str


def examine_rig(
    rig: Rig,
    *,
    gantry_port: str | None = None,
    stage_address: str | None = None,
    camera_endpoint: str | None = None,
    camera: bool = True,
) -> list[Finding]:
    """Every device of ``rig`` in turn (the camera unless ``camera`` is False); a device that cannot be
    reached is a finding, not an exception. The devices are locked as a run locks them: a rig in use by
    a run is one finding naming the run, and nothing of it is touched."""
    links = Links(gantry_port, stage_address, camera_endpoint)
    used = [(what, link) for what, link in rig_device_links(rig, links) if camera or what != "the camera"]
    try:
        with hold_devices(used):
            found = _examine_stage(rig, stage_address) + _examine_gantry(rig, gantry_port)
            found += _examine_camera(rig, camera_endpoint) if camera else []
    except Busy as exc:
        return [Finding("rig", "problem", str(exc))]
    return found + calibration_findings(rig, time.time())


CALIBRATIONS = ("camera", "gantry", "radiometric")  # each one an hlr-lab calibrate procedure
STALE_DAYS = 90  # a calibration older than this is worth repeating (a knock, a lamp changed, a season)


def calibration_findings(rig: Rig, now: float) -> list[Finding]:
    """How old each calibration of the rig file is, or that it was never done (``[calibration.*]``)."""
    found = []
    for procedure in CALIBRATIONS:
        record = getattr(rig.file.calibration, procedure)
        device = f"calibration: {procedure}"
        if record is None:
            found.append(Finding(device, "warning", f"never calibrated: run hlr-lab calibrate {procedure}"))
            continue
        try:
            when = datetime.strptime(record.date, "%Y-%m-%dT%H:%M:%S%z").timestamp()
        except ValueError:
            found.append(Finding(device, "warning", f"the record's date {record.date!r} cannot be read"))
            continue
        days = (now - when) / 86400
        level = "warning" if days > STALE_DAYS else "ok"
        advice = f"; older than {STALE_DAYS} days: consider calibrating again" if level == "warning" else ""
        if SYSTEMATIC_FIELDS[procedure] not in (record.model_extra or {}):
            advice += (
                f"; its record has no {SYSTEMATIC_FIELDS[procedure]} (an older hlr-lab): fit's systematic "
                "uncertainties fall back on its standard errors or a conservative default — calibrate again"
            )
        found.append(Finding(device, level, f"done {record.date[:10]} ({days:.0f} days ago){advice}"))
    return found


def diagnose_servo(report: ServoReport) -> list[Finding]:
    """What one servo's report means: a wrong ID, a hardware alarm, its temperature and supply voltage, its
    position against the rig file's limits; else its identity and state."""
    axis = report.axis
    device = f"servo {axis.servo_id} ({axis.label})"
    found = []
    if report.model.startswith("model "):
        found.append(Finding(device, "problem", f"{report.model}: check the servo ID in the rig file"))
    if report.hardware_error:
        found.append(
            Finding(
                device,
                "problem",
                f"hardware error ({', '.join(report.hardware_error)}); its torque stays off until a reboot. "
                "Find the cause (load, heat, supply), then reboot it with Dynamixel Wizard or set "
                "gantry.reboot_on_alarm = true for one run",
            )
        )
    if report.temperature_c >= report.temperature_limit_c:
        found.append(
            Finding(
                device,
                "problem",
                f"{report.temperature_c} °C, at its limit of {report.temperature_limit_c} °C: let it cool",
            )
        )
    elif report.temperature_c >= report.temperature_limit_c - HOT_MARGIN_C:
        found.append(
            Finding(
                device,
                "warning",
                f"{report.temperature_c} °C, near its limit of {report.temperature_limit_c} °C: "
                "lower gantry.profile_velocity or let it rest",
            )
        )
    lo_v, hi_v = report.voltage_limits_v
    if not lo_v <= report.voltage_v <= hi_v:
        found.append(
            Finding(
                device,
                "problem",
                f"supply {report.voltage_v:.1f} V is outside {lo_v:.1f}–{hi_v:.1f} V: check the power supply",
            )
        )
    if not axis.min_ticks <= report.position <= axis.max_ticks:
        # position mode spans one turn without wrapping, so the first move goes straight back into range
        found.append(
            Finding(
                device,
                "warning",
                f"at tick {report.position}, outside the rig's limits [{axis.min_ticks}, {axis.max_ticks}]: "
                "the first move brings it back into range; make sure the arm's path is clear",
            )
        )
    if not found:
        torque = "torque on" if report.torque_on else "torque off"
        found.append(
            Finding(
                device,
                "ok",
                f"{report.model}, firmware {report.firmware}, at tick {report.position}, {torque}, "
                f"{report.temperature_c} °C, {report.voltage_v:.1f} V",
            )
        )
    return found


def diagnose_drive(
    report: DriveReport, config: StageConfig, kinematics: TurntableKinematics
) -> list[Finding]:
    """What the turntable drive's report means: an alarm, its position against the rig file's limits, its
    readiness; else where it is (steps and degrees)."""
    device = f"turntable on {config.address}"
    if report.alarm:
        return [
            Finding(
                device,
                "problem",
                f"drive alarm 0x{report.alarm:02x}: clear its cause, then reset it on the drive or set "
                "turntable.reset_alarm = true",
            )
        ]
    if not config.min_steps <= report.position <= config.max_steps:
        return [
            Finding(
                device,
                "problem",
                f"at {report.position} steps, outside the rig's limits [{config.min_steps}, "
                f"{config.max_steps}]: home the stage, or check turntable.zero_steps",
            )
        ]
    where = f"at {report.position} steps ({kinematics.degrees_for(report.position):.2f}°)"
    if not report.ready:
        return [Finding(device, "warning", f"{where}, not ready: check the drive's excitation (FREE input)")]
    return [Finding(device, "ok", f"ready, {where}")]


def _examine_stage(rig: Rig, address: str | None) -> list[Finding]:
    try:
        config = stage_config(rig, address)
        stage = ModbusStage(config)
    except HlrLabError as exc:
        return [Finding("turntable", "problem", str(exc))]
    try:
        found = _ask(
            f"turntable on {config.address}",
            lambda: diagnose_drive(stage.inspect(), config, rig.turntable_kinematics),
            silent=f"no answer on {config.address}: check that the drive is powered and on the network, and "
            "turntable.address (host:port) and device_id in the rig file (its vendor's Modbus tool can scan)",
        )
        lamp = rig.file.lamp
        if lamp is not None:
            relay = ModbusRelay(stage, lamp.device_id, lamp.coil)
            device = f"lamp relay (device {lamp.device_id}, coil {lamp.coil})"
            if found[0].level == "problem" and found[0].message.startswith("no answer"):
                # the relay is reached through the turntable's link: the same question would fail the same way
                found.append(
                    Finding(device, "problem", "not asked: the turntable's Modbus link does not answer")
                )
            else:
                found += _ask(device, lambda: [_lamp_finding(device, relay.get())])
        return found
    finally:
        stage.close()


def _lamp_finding(device: str, on: bool) -> Finding:
    if on:
        return Finding(device, "warning", "the lamp is on (it should be off between runs)")
    return Finding(device, "ok", "answers; the lamp is off")


def _examine_gantry(rig: Rig, port: str | None) -> list[Finding]:
    try:
        gantry = DynamixelGantry(gantry_config(rig, port))
    except HlrLabError as exc:
        return [Finding("gantry", "problem", str(exc))]
    try:
        found = []
        for axis in gantry.config.axes:
            device = f"servo {axis.servo_id} ({axis.label})"
            found += _ask(
                device,
                lambda a=axis: diagnose_servo(gantry.inspect(a)),
                silent=f"no reply: check its power and cable, and that its ID is {axis.servo_id} and its "
                f"baud rate {gantry.config.baudrate} (Dynamixel Wizard can scan the bus)",
            )
        return found
    finally:
        gantry.close(torque_off=False)  # leave the torque as it was: the doctor changes nothing


def _examine_camera(rig: Rig, endpoint: str | None) -> list[Finding]:
    """Opening is the check: it reaches the device and sets the frame format (no exposure is taken)."""
    try:
        camera = open_camera(rig, endpoint)
    except HlrLabError as exc:
        return [Finding("camera", "problem", str(exc))]
    try:
        describe = getattr(camera, "describe", None)  # a GenICam camera says what it is
        about = describe() if describe else {}
    finally:
        camera.close()
    if not about:
        return [Finding("camera", "ok", "opens and takes the frame format")]
    said = [f"{about.get('vendor', '?')} {about.get('model', '?')}, serial {about.get('serial', '?')}"]
    if "firmware" in about:
        said.append(f"firmware {about['firmware']}")
    said.append(f"pixel format {about['pixel_format']} of {', '.join(about['pixel_formats'])}")
    said.append(f"exposure {1e3 * about['exposure_s']:g} ms")
    if "temperature_c" in about:
        said.append(f"{about['temperature_c']:.1f} °C")
    found = [Finding("camera", "ok", "opens and takes the frame format: " + "; ".join(said))]
    if advice := about.get("receive_buffer_advice"):  # GigE Vision: a frame's packets outrun the socket
        found.append(Finding("camera", "warning", advice))
    return found


def _ask(device: str, question: Callable[[], list[Finding]], silent: str | None = None) -> list[Finding]:
    try:
        return question()
    except DeviceTimeout as exc:
        return [Finding(device, "problem", silent or str(exc))]
    except HlrLabError as exc:
        return [Finding(device, "problem", str(exc))]
