"""The turntable and lamp drivers against the simulated stage: a real pymodbus client and server."""

import pytest

from drivers.errors import DeviceError, DeviceFault, DeviceTimeout, HardwareAlarm, LimitError
from drivers.modbus_stage import ModbusRelay, ModbusStage, StageConfig
from drivers.protocols import Positioner, Switch
from sim.turntable.server import TurntableServer


@pytest.fixture
def server():
    with TurntableServer.simulated(speed_factor=20.0) as s:
        yield s


def stage_on(address, **kw) -> ModbusStage:
    return ModbusStage(StageConfig(address, -9000, 9000, timeout_s=0.3, backoff_s=0.001, **kw))


def test_move_settle_and_lamp(server):
    host, port = server.serve_tcp()
    stage = stage_on(f"{host}:{port}")
    assert isinstance(stage, Positioner)
    stage.connect()
    stage.move_to((4500,))
    assert stage.wait_settled(5) == (4500,)
    assert server.stage.moves == [4500]
    lamp = ModbusRelay(stage)
    assert isinstance(lamp, Switch)
    lamp.set(True)
    assert lamp.get()
    assert server.stage.lamp
    lamp.set(False)
    assert not server.stage.lamp
    stage.home(5)
    assert stage.position() == (0,)
    stage.close()


def test_limits_are_refused_before_sending(server):
    host, port = server.serve_tcp()
    stage = stage_on(f"{host}:{port}")
    stage.connect()
    with pytest.raises(LimitError, match="outside"):
        stage.move_to((12_000,))
    assert server.stage.moves == []
    stage.close()


def test_drive_alarms_are_reported(server):
    host, port = server.serve_tcp()
    wide = ModbusStage(
        StageConfig(f"{host}:{port}", -50_000, 50_000, timeout_s=0.3)
    )  # wider than the drive's
    wide.connect()
    wide.move_to((30_000,))
    with pytest.raises(HardwareAlarm, match="alarm 0x67"):
        wide.wait_settled(2)
    with pytest.raises(HardwareAlarm, match="allow an alarm reset"):
        wide.connect()  # a drive in alarm is refused unless a reset is allowed
    allowed = ModbusStage(StageConfig(f"{host}:{port}", -9000, 9000, reset_alarm=True))
    allowed.connect()
    assert server.stage.alarm == 0
    wide.close()
    allowed.close()


def test_link_faults(server):
    host, port = server.serve_tcp()
    stage = stage_on(f"{host}:{port}", retries=2)
    stage.connect()
    server.faults.no_reply = 1
    assert stage.position() == (0,)  # retried
    assert stage.retried == 1
    server.faults.exception = 1
    with pytest.raises(DeviceFault, match="exception 4") as err:
        stage.position()
    assert err.value.code == 4
    server.disconnect_clients()
    assert stage.position() == (0,)  # reconnected on the retry
    server.faults.no_reply = 10
    with pytest.raises(DeviceTimeout):
        stage.position()
    stage.close()


def test_rtu_and_unreachable(server):
    stage = stage_on(server.serve_rtu())
    stage.connect()
    stage.move_to((-800,))
    assert stage.wait_settled(5) == (-800,)
    stage.close()
    with pytest.raises(DeviceError, match="cannot connect"):
        stage_on("127.0.0.1:1")
