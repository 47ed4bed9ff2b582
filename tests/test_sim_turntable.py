"""The simulated rotary stage and lamp relay, through a real pymodbus client over TCP and RTU."""

import time

import pytest
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusIOException

from sim.turntable import register_map as rm
from sim.turntable.server import TurntableServer
from sim.turntable.stage import RotaryStage


class ManualClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_trapezoidal_move_and_timing():
    clock = ManualClock()
    stage = RotaryStage(clock)
    stage.data.update({rm.TARGET: 5000, rm.SPEED: 1000, rm.ACCELERATION: 2000, rm.DECELERATION: 1000})
    stage.start()
    # ramp up 0.5 s (250 steps), ramp down 1 s (500 steps), cruise 4.25 s for the other 4250 steps
    total = 0.5 + 4.25 + 1.0
    positions = []
    while clock.t < total:
        positions.append(stage.position())
        assert stage.moving()
        assert stage.status() & rm.MOVE
        clock.t += 0.05
    clock.t = total + 1e-9
    assert positions == sorted(positions)
    assert stage.position() == 5000
    assert not stage.moving()
    assert stage.status() == rm.READY | rm.IN_POS
    assert abs(stage.velocity()) == 0


def test_limits_alarms_homing_and_free():
    clock = ManualClock()
    stage = RotaryStage(clock, limits=(-100, 100))
    stage.data[rm.TARGET] = 500
    stage.set_command(rm.START)
    assert stage.alarm == rm.ALARM_OVERTRAVEL
    assert stage.position() == 0
    assert stage.status() & rm.ALARM
    stage.set_command(0)
    stage.data[rm.TARGET] = 50
    stage.set_command(rm.START)
    assert stage.position() == 0  # a drive in alarm does not move
    stage.set_command(rm.ALARM_RESET)
    stage.set_command(rm.START | rm.ALARM_RESET)  # START's rising edge
    clock.t = 10
    assert stage.position() == 50
    stage.set_command(rm.ZHOME)
    clock.t = 20
    assert stage.position() == 0
    assert stage.status() & rm.HOME_END
    stage.set_command(rm.FREE)
    stage.data[rm.TARGET] = 80
    stage.set_command(rm.FREE | rm.START)
    clock.t = 30
    assert stage.position() == 0  # de-energised
    assert stage.moves == [500, 50, 50, 80]


@pytest.fixture
def tcp():
    with TurntableServer.simulated(speed_factor=20.0) as server:
        host, port = server.serve_tcp()
        client = ModbusTcpClient(host, port=port, timeout=0.5, retries=0)
        assert client.connect()
        yield server, client
        client.close()


def int32(client, v):
    return client.convert_to_registers(v, client.DATATYPE.INT32)


def read_int32(client, address, n=1):
    rr = client.read_holding_registers(address, count=2 * n, device_id=rm.STAGE_UNIT)
    assert not rr.isError(), rr
    return [
        client.convert_from_registers(rr.registers[2 * i : 2 * i + 2], client.DATATYPE.INT32)
        for i in range(n)
    ]


def wait_for(predicate, timeout=3.0):
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_direct_data_operation_over_tcp(tcp):
    """The AZ's direct data operation: type, position, speed, rates, current and a trigger of 1 in one
    FC16 start the move; status, alarm and feedback position follow; the trigger reads 0 once it acted.
    A negative trigger makes the next write of one item (−5: the position) start a move."""
    server, c = tcp
    block = [word for v in (rm.ABSOLUTE, 3600, 4000, 8000, 8000, 500, rm.TRIGGER_ALL) for word in int32(c, v)]
    assert not c.write_registers(rm.OP_TYPE, block, device_id=rm.STAGE_UNIT).isError()  # one FC16
    assert read_int32(c, rm.STATUS)[0] & rm.MOVE
    assert read_int32(c, rm.TRIGGER)[0] == 0
    wait_for(lambda: read_int32(c, rm.STATUS)[0] & rm.IN_POS)
    status, alarm = read_int32(c, rm.STATUS, 2)
    position, velocity = read_int32(c, rm.POSITION)[0], read_int32(c, rm.VELOCITY)[0]
    assert (position, velocity, alarm) == (3600, 0, 0)
    assert status & rm.READY
    assert server.stage.moves == [3600]
    assert not c.write_registers(rm.TRIGGER, int32(c, -5), device_id=rm.STAGE_UNIT).isError()
    assert not c.write_registers(rm.TARGET, int32(c, -1200), device_id=rm.STAGE_UNIT).isError()
    wait_for(lambda: read_int32(c, rm.POSITION)[0] == -1200)
    assert read_int32(c, rm.TRIGGER)[0] == -5  # a negative trigger stays
    assert server.stage.moves == [3600, -1200]


def test_exceptions_for_bad_values_and_addresses(tcp):
    _, c = tcp
    for address, value in ((rm.SPEED, 0), (rm.OP_TYPE, 7), (rm.CURRENT, 2000), (rm.ACCELERATION, -5)):
        rr = c.write_registers(address, int32(c, value), device_id=rm.STAGE_UNIT)
        assert rr.isError()
        assert rr.exception_code == 3
    rr = c.write_registers(rm.POSITION, int32(c, 0), device_id=rm.STAGE_UNIT)  # read-only
    assert rr.isError()
    assert rr.exception_code == 2
    rr = c.read_holding_registers(0, count=2, device_id=rm.STAGE_UNIT)  # not in the map
    assert rr.isError()
    assert rr.exception_code == 2


def test_overtravel_alarm_over_modbus(tcp):
    server, c = tcp
    c.write_registers(rm.TARGET, int32(c, 50_000), device_id=rm.STAGE_UNIT)
    c.write_registers(rm.COMMAND, int32(c, rm.START), device_id=rm.STAGE_UNIT)
    status, alarm = read_int32(c, rm.STATUS, 2)
    assert status & rm.ALARM
    assert alarm == rm.ALARM_OVERTRAVEL
    c.write_registers(rm.COMMAND, int32(c, rm.ALARM_RESET), device_id=rm.STAGE_UNIT)
    assert read_int32(c, rm.ALARM_CODE)[0] == 0
    assert server.stage.position() == 0


def test_lamp_relay_coil(tcp):
    server, c = tcp
    assert not server.stage.lamp
    assert not c.write_coil(rm.LAMP_COIL, True, device_id=rm.RELAY_UNIT).isError()
    assert server.stage.lamp
    assert c.read_coils(rm.LAMP_COIL, count=1, device_id=rm.RELAY_UNIT).bits[0]
    c.write_coil(rm.LAMP_COIL, False, device_id=rm.RELAY_UNIT)
    assert not server.stage.lamp


def test_injected_faults(tcp):
    server, c = tcp
    server.faults.exception = 1
    rr = c.read_holding_registers(rm.STATUS, count=2, device_id=rm.STAGE_UNIT)
    assert rr.isError()
    assert rr.exception_code == 4
    server.faults.no_reply = 1
    with pytest.raises(ModbusIOException):
        c.read_holding_registers(rm.STATUS, count=2, device_id=rm.STAGE_UNIT)
    server.stage.fault()
    assert read_int32(c, rm.ALARM_CODE)[0] == rm.ALARM_OVERLOAD
    server.disconnect_clients()
    time.sleep(0.1)
    with pytest.raises(ConnectionException):  # the link is gone: the next request fails…
        c.read_holding_registers(rm.STATUS, count=2, device_id=rm.STAGE_UNIT)
    c.close()
    assert c.connect()  # …and the client can come back
    assert read_int32(c, rm.ALARM_CODE)[0] == rm.ALARM_OVERLOAD


def test_rtu_over_a_pty():
    with TurntableServer.simulated(speed_factor=50.0) as server:
        path = server.serve_rtu()
        c = ModbusSerialClient(path, baudrate=115_200, timeout=1, retries=0)
        assert c.connect()
        c.write_registers(rm.TARGET, int32(c, 700), device_id=rm.STAGE_UNIT)
        c.write_registers(rm.COMMAND, int32(c, rm.START), device_id=rm.STAGE_UNIT)
        wait_for(lambda: read_int32(c, rm.POSITION)[0] == 700)
        assert not c.write_coil(rm.LAMP_COIL, True, device_id=rm.RELAY_UNIT).isError()
        assert server.stage.lamp
        c.close()
