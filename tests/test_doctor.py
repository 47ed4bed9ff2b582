"""``hlr-lab doctor`` on the simulated rig: healthy, with injected faults, and with devices missing."""

import os
import re
from dataclasses import replace
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.dynamixel import Axis, ServoReport
from hlr_lab.cli.main import main
from hlr_lab.instrument.doctor import diagnose_servo, examine_rig
from hlr_lab.instrument.locks import hold_devices
from hlr_lab.rig.file import load_rig, rig_of_snapshot
from sim.dynamixel.servo import OVERLOAD
from sim.rig import SimRig
from sim.turntable import register_map as rm


def examine(sim, rig, **kw):
    """The devices' findings (the calibration records' are tested on their own)."""
    e = sim.endpoints
    found = examine_rig(
        rig, gantry_port=kw.get("port", e.dynamixel), stage_address=kw.get("address", e.modbus), camera=False
    )
    return [f for f in found if not f.device.startswith("calibration")]


def by_device(findings):
    return {f.device.split(" on ")[0]: f for f in findings}


def test_a_healthy_rig_is_reported_and_left_untouched(rig):
    with SimRig(speed_factor=40.0) as sim:
        findings = examine(sim, rig)
        assert [f.level for f in findings] == ["ok"] * 4
        found = by_device(findings)
        assert "XM430-W350" in found["servo 2 (elevation)"].message
        assert "at tick 1024" in found["servo 2 (elevation)"].message
        assert "lamp is off" in found["lamp relay (device 2, coil 0)"].message
        # read-only: no goal sent, no torque switched on, nothing written to the EEPROM
        assert sim.bus.goals == []
        assert all(s.get("torque_enable") == 0 for s in sim.bus.servos)
        assert all(s.get("max_position_limit") == 4095 for s in sim.bus.servos)


def test_faults_are_named_with_what_to_do(rig):
    with SimRig(speed_factor=40.0) as sim:
        sim.bus.servo(2).hardware_fault(OVERLOAD)
        sim.turntable.stage.alarm = rm.ALARM_OVERLOAD
        host, port = sim.endpoints.modbus.split(":")
        with ModbusTcpClient(host, port=int(port), timeout=1, retries=0) as client:  # someone left it on
            assert not client.write_coil(rm.LAMP_COIL, True, device_id=rm.RELAY_UNIT).isError()
        found = by_device(examine(sim, rig))
    servo = found["servo 2 (elevation)"]
    assert servo.level == "problem"
    assert "overload" in servo.message
    assert "reboot_on_alarm" in servo.message
    assert found["servo 1 (azimuth)"].level == "ok"
    stage = found["turntable"]
    assert stage.level == "problem"
    assert "alarm 0x30" in stage.message
    assert "reset_alarm" in stage.message
    assert found["lamp relay (device 2, coil 0)"].level == "warning"


def test_missing_devices_are_findings_not_crashes(rig):
    with SimRig(speed_factor=40.0, servo_ids=(1,)) as sim:  # servo 2 unplugged
        found = by_device(examine(sim, rig, address="127.0.0.1:1"))
    assert found["servo 1 (azimuth)"].level == "ok"
    missing = found["servo 2 (elevation)"]
    assert missing.level == "problem"
    assert "no reply" in missing.message
    assert "ID is 2" in missing.message
    assert found["turntable"].level == "problem"
    assert "cannot connect" in found["turntable"].message


def report(**change) -> ServoReport:
    healthy = ServoReport(
        axis=Axis(2, 910, 1934, "elevation"),
        model="XM430-W350",
        firmware=48,
        hardware_error=(),
        torque_on=False,
        position=1024,
        stored_limits=(0, 4095),
        temperature_c=35,
        temperature_limit_c=80,
        voltage_v=12.0,
        voltage_limits_v=(9.5, 16.0),
    )
    return replace(healthy, **change)


@pytest.mark.parametrize(
    ("change", "level", "words"),
    [
        ({}, "ok", "XM430-W350"),
        ({"temperature_c": 72}, "warning", "near its limit of 80"),
        ({"temperature_c": 80}, "problem", "let it cool"),
        ({"voltage_v": 9.0}, "problem", "check the power supply"),
        ({"position": 2048}, "warning", "outside the rig's limits [910, 1934]"),
        ({"model": "model 77 (not an X-series servo this driver knows)"}, "problem", "servo ID"),
    ],
)
def test_servo_diagnoses(change, level, words):
    (finding,) = diagnose_servo(report(**change))
    assert finding.level == level
    assert words in finding.message


def test_cli_exit_status(tmp_path, capsys):
    assert main(["doctor", "--sim"]) == 0
    err = capsys.readouterr().err
    assert "the rig is ready" in err
    assert re.search(r"camera\s*│\s*ok\s*│\s*opens and takes the frame format", err)
    # the simulated camera is a GigE Vision one: it says what it is, as the servos do
    flat = re.sub(r"[│\s]+", " ", err)  # the table's cells wrap
    assert re.search(r"hlr-lab Simulated reflectance camera, serial SIM0\d{3}\b", flat)  # SIM0 + its address
    assert "pixel format RGB12 of Mono8," in flat
    # a rig file whose links lead nowhere: three problems, one line saying so, exit status 1
    text = (Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml").read_text()
    text = text.replace("[gantry]", 'address = "127.0.0.1:1"\n\n[gantry]')
    text = text.replace("[turntable]", 'port = "/dev/hlr-lab-no-such-port"\n\n[turntable]')
    text = text.replace("[lamp]", 'address = "127.0.0.1:1"\n\n[lamp]')
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(text)
    assert main(["doctor", "--rig", str(rig_file)]) == 1
    err = capsys.readouterr().err
    assert "3 problem(s)" in err
    assert "camera on 127.0.0.1:1: cannot connect" in err


def test_a_port_that_does_not_open_is_one_finding(rig):
    findings = examine_rig(rig, gantry_port="/dev/hlr-lab-no-such-port", stage_address="127.0.0.1:1")
    findings = [f for f in findings if not f.device.startswith("calibration")]
    assert [(f.device, f.level) for f in findings] == [
        ("turntable", "problem"),
        ("gantry", "problem"),
        ("camera", "problem"),
    ]
    assert "no address" in findings[2].message
    assert "cannot open the port" in findings[1].message
    assert "/dev/hlr-lab-no-such-port" in findings[1].message


def test_a_rig_in_use_by_a_run_is_one_finding_and_left_untouched(rig):
    """The doctor takes the device locks a run holds: while another process (here: this one) holds the
    servo bus, the doctor names the holder and asks nothing of any device."""
    with SimRig(speed_factor=40.0) as sim:
        e = sim.endpoints
        with hold_devices([("the gantry's servo bus", e.dynamixel)]):
            requests = sim.turntable.requests
            findings = examine(sim, rig)
            assert [(f.device, f.level) for f in findings] == [("rig", "problem")]
            assert f"is in use by PID {os.getpid()}" in findings[0].message
            assert sim.turntable.requests == requests  # not even the turntable was asked
        assert [f.level for f in examine(sim, rig)] == ["ok"] * 4  # released: examined as usual


def test_the_age_of_each_calibration_is_reported(rig):
    """Never calibrated: a warning saying which command to run; calibrated: its date and age, a warning
    once older than 90 days, and a word when its record lacks what the systematic uncertainty needs."""
    from datetime import datetime

    from hlr_lab.instrument.doctor import calibration_findings

    never = {f.device: f for f in calibration_findings(rig, 0.0)}
    assert never["calibration: camera"].level == "warning"
    assert "never calibrated: run hlr-lab calibrate camera" in never["calibration: camera"].message
    record = {"date": "2026-11-01T10:00:00+0000", "hlr_lab": "0.1.0", "rms_px": 0.1}
    snapshot = rig.file.model_dump(mode="json")
    done = rig_of_snapshot({**snapshot, "calibration": {**snapshot["calibration"], "camera": record}}, "test")
    soon = datetime(2026, 11, 11, 10, tzinfo=datetime.now().astimezone().tzinfo).timestamp()
    found = {f.device: f for f in calibration_findings(done, soon)}["calibration: camera"]
    assert (found.level, found.message[:16]) == ("ok", "done 2026-11-01 ")
    assert "has no covariance (an older hlr-lab)" in found.message  # the systematic part needs it
    late = {f.device: f for f in calibration_findings(done, soon + 100 * 86400)}["calibration: camera"]
    assert late.level == "warning"
    current = {**record, "covariance_of": ["fx_px"], "covariance": [[0.1]]}
    now = rig_of_snapshot({**snapshot, "calibration": {**snapshot["calibration"], "camera": current}}, "test")
    found = {f.device: f for f in calibration_findings(now, soon)}["calibration: camera"]
    assert "covariance" not in found.message


def test_the_example_rig_file_on_a_bench_with_nothing_plugged_in(tmp_path, capfd):
    """docs/rig.example.toml where a Modbus server accepts and drops every connection, no serial port and
    no camera: one row per device in hlr-lab's words with what to do (no OpenCV log line, no pymodbus
    text), the lamp relay not asked again over the turntable's dead link, every calibration's command."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def drop_every_connection() -> None:
        server.settimeout(0.1)
        while not stop.is_set():
            try:
                server.accept()[0].close()
            except TimeoutError:
                continue

    dropper = threading.Thread(target=drop_every_connection)
    dropper.start()
    try:
        text = (Path(__file__).resolve().parents[1] / "docs" / "rig.example.toml").read_text()
        text = text.replace('"192.168.0.30:502"', f'"127.0.0.1:{server.getsockname()[1]}"')
        text = text.replace("/dev/serial/by-id/usb-FTDI_USB__-__Serial_Converter_FT4TFSV1-if00-port0",
                            str(tmp_path / "no-such-port"))  # fmt: skip
        text = text.replace('"/dev/video0"', f'"{tmp_path / "no-such-camera"}"')
        rig_file = tmp_path / "rig.toml"
        rig_file.write_text(text)
        assert main(["doctor", "--rig", str(rig_file)]) == 1
        found = by_device(examine_rig(load_rig(rig_file)))
    finally:
        stop.set()
        dropper.join()
        server.close()
    out = capfd.readouterr()
    printed = out.out + out.err
    assert "[ WARN" not in printed  # OpenCV's own log line
    assert "unbounded" not in printed  # pymodbus's own words
    assert found["turntable"].message.startswith("no answer on 127.0.0.1")
    assert "device_id in the rig file" in found["turntable"].message
    assert (
        found["lamp relay (device 2, coil 0)"].message
        == "not asked: the turntable's Modbus link does not answer"
    )
    assert found["calibration: radiometric"].message == "never calibrated: run hlr-lab calibrate radiometric"
    assert "cannot open the port" in found["gantry"].message
    assert "cannot open; check the device path" in found["camera"].message


def test_a_socket_buffer_smaller_than_a_frame_is_a_warning_with_the_command(tmp_path, monkeypatch, capsys):
    """A kernel that caps a socket's receive buffer below a frame (net.core.rmem_max): a loaded computer drops
    the rest of each frame and the camera must resend it (docs/camera.md). The doctor says so with the
    command that fixes it; with room for a frame it says nothing. (The kernel's file is replaced by one of
    known content: the test must not depend on this machine's setting.)"""
    import drivers.genicam_camera as genicam

    cap = tmp_path / "rmem_max"
    monkeypatch.setattr(genicam, "RMEM_MAX", cap)
    cap.write_text("4194304\n")
    assert main(["doctor", "--sim"]) == 0  # a warning: the run works, with resends
    flat = re.sub(r"[│\s]+", " ", capsys.readouterr().err)
    # the simulated camera's RGB12 frame: 1280 × 960 × 3 × 2 bytes, and its chunks
    assert (
        "caps a socket's receive buffer at 4,194,304 bytes (net.core.rmem_max), less than a frame's 7,374,936"
        in flat
    )
    assert "sudo sysctl -w net.core.rmem_max=8388608" in flat
    cap.write_text("16777216\n")
    assert main(["doctor", "--sim"]) == 0
    assert "rmem_max" not in capsys.readouterr().err
    cap.unlink()  # not Linux: nothing to say
    assert main(["doctor", "--sim"]) == 0
    assert "rmem_max" not in capsys.readouterr().err
