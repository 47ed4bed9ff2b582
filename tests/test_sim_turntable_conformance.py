"""The simulated stage and lamp relay answer as the Modbus Application Protocol (v1.1b3) says a device
does, seen by clients that are not pymodbus: raw frames on a socket, pyModbusTCP, libmodbus's mbpoll
(TCP and RTU), and over RTU minimalmodbus (its own framing and CRC). And no frame, however broken, stops
the server or prints a traceback."""

from __future__ import annotations

import logging
import random
import re
import shutil
import socket
import struct
import subprocess
import time

import minimalmodbus
import pytest
from pyModbusTCP.client import ModbusClient

from sim.turntable import register_map as rm
from sim.turntable.server import TurntableServer


@pytest.fixture
def server():
    with TurntableServer.simulated(speed_factor=20.0) as srv:
        host, port = srv.serve_tcp()
        yield srv, host, port


def ask(host: str, port: int, unit: int, pdu: bytes, transaction: int = 7) -> bytes:
    """One request (MBAP header + ``pdu``) on a fresh connection; the reply's PDU (b"" when none)."""
    with socket.create_connection((host, port), timeout=2) as s:
        s.sendall(struct.pack(">HHHB", transaction, 0, len(pdu) + 1, unit) + pdu)
        try:
            reply = s.recv(512)
        except TimeoutError:
            return b""
    assert reply[:4] == struct.pack(">HH", transaction, 0)  # same transaction, protocol 0
    assert reply[6] == unit
    return reply[7:]


def words(value: int) -> bytes:
    return struct.pack(">i", value)


@pytest.mark.parametrize(
    ("what", "unit", "pdu", "reply"),
    [
        ("read 0 registers", 1, bytes([3, 0, 0, 0, 0]), bytes([0x83, 3])),
        ("read 126 registers", 1, bytes([3, 0, 0, 0, 126]), bytes([0x83, 3])),
        ("read 0 coils", 2, bytes([1, 0, 0, 0, 0]), bytes([0x81, 3])),
        ("an unknown function", 1, bytes([0x41, 0, 0]), bytes([0xC1, 1])),
        ("input registers of the stage", 1, bytes([4, 0, rm.STATUS, 0, 2]), bytes([0x84, 1])),
        ("coils of the stage", 1, bytes([1, 0, rm.STATUS, 0, 1]), bytes([0x81, 1])),
        ("registers of the relay", 2, bytes([3, 0, 0, 0, 1]), bytes([0x83, 1])),
        ("a coil value that is neither on nor off", 2, bytes([5, 0, 0, 0x12, 0x34]), bytes([0x85, 3])),
        ("a unit that is not there", 9, bytes([3, 0, 0, 0, 1]), bytes([0x83, 0x0B])),
        ("a register beyond the map", 1, bytes([3, 0, 200, 0, 2]), bytes([0x83, 2])),
        ("speed 0 through its low half", 1, bytes([6, 0, rm.SPEED + 1, 0, 0]), bytes([0x86, 3])),
        ("a diagnostic that does not exist", 1, bytes([8, 0x12, 0x34, 0, 0]), bytes([0x88, 1])),
        ("an exception code as a request", 1, bytes([0x83, 2]), bytes([0x83, 1])),
        ("diagnostics: return the query data", 1, bytes([8, 0, 0, 0x12, 0x34]), bytes([8, 0, 0, 0x12, 0x34])),
    ],
    ids=lambda v: v if isinstance(v, str) else "",
)
def test_exception_replies_as_the_specification_says(server, what, unit, pdu, reply):
    _, host, port = server
    assert ask(host, port, unit, pdu) == reply


def test_coil_values_on_and_off_switch_the_lamp(server):
    srv, host, port = server
    assert ask(host, port, 2, bytes([5, 0, 0, 0xFF, 0])) == bytes([5, 0, 0, 0xFF, 0])
    assert srv.stage.lamp
    assert ask(host, port, 2, bytes([5, 0, 0, 0x12, 0x34]))[0] == 0x85
    assert srv.stage.lamp  # the refused write changed nothing
    assert ask(host, port, 2, bytes([5, 0, 0, 0, 0])) == bytes([5, 0, 0, 0, 0])
    assert not srv.stage.lamp


def test_a_fresh_drive_shows_the_operation_data_it_will_use(server):
    """pyModbusTCP reads the data registers of a drive nobody wrote to: they say what a move would use
    (absolute, speed 2000, acceleration and deceleration 4000, current 500), not zeros."""
    _, host, port = server
    client = ModbusClient(host=host, port=port, unit_id=rm.STAGE_UNIT, auto_open=True, timeout=2)
    regs = client.read_holding_registers(rm.OP_TYPE, 12)
    values = [struct.unpack(">i", struct.pack(">HH", regs[i], regs[i + 1]))[0] for i in range(0, 12, 2)]
    assert values == [rm.ABSOLUTE, 0, 2000, 4000, 4000, 500]
    client.close()


def test_a_32_bit_field_written_one_half_at_a_time_is_taken_whole(server):
    """FC 6 to each half of Speed (pyModbusTCP's write_single_register): the move runs at the speed the
    two halves make, and a half that would make it 0 or negative is exception 3, changing nothing."""
    srv, host, port = server
    client = ModbusClient(host=host, port=port, unit_id=rm.STAGE_UNIT, auto_open=True, timeout=2)
    assert client.write_single_register(rm.SPEED + 1, 500)  # low half; the high half is 0
    assert srv.stage.data[rm.SPEED] == 500
    for half, value in ((rm.SPEED, 1), (rm.SPEED + 1, 0), (rm.SPEED, 0x8000)):  # 66 036 (too fast), 0, < 0
        assert not client.write_single_register(half, value)
        assert client.last_except == 3
    assert srv.stage.data[rm.SPEED] == 500
    for address, value in ((rm.TARGET, 0), (rm.TARGET + 1, 1200), (rm.TRIGGER + 1, 1)):
        assert client.write_single_register(address, value)
    assert srv.stage.moves == [1200]
    client.close()


def test_a_client_that_talks_to_an_az_as_oriental_motors_examples_do(server):
    """pyModbusTCP used the way Oriental Motor's sample code drives an AZ: the driver input command's lower
    word alone at 007Dh, 32-bit reads of status, alarm and feedback position, a direct data operation in
    one write with trigger 1, a pulsed STOP, the alarm reset and P-PRESET maintenance commands written
    1 then 0; and a one-register read of a status word's lower half."""
    srv, host, port = server
    client = ModbusClient(host=host, port=port, unit_id=rm.STAGE_UNIT, auto_open=True, timeout=2)

    def int32(address: int) -> int:
        hi, lo = client.read_holding_registers(address, 2)
        return struct.unpack(">i", struct.pack(">HH", hi, lo))[0]

    def halves(*values: int) -> list[int]:
        return [w for v in values for w in struct.unpack(">HH", struct.pack(">i", v))]

    assert client.read_holding_registers(rm.COMMAND + 1, 1) == [0]
    operation = halves(0, rm.ABSOLUTE, 3600, 4000, 1_000_000, 1_000_000, 1000, rm.TRIGGER_ALL, 0)
    assert client.write_multiple_registers(rm.DATA_NO, operation)
    assert srv.stage.moves == [3600]
    deadline = time.monotonic() + 5
    while int32(rm.STATUS) & rm.MOVE:
        assert time.monotonic() < deadline
    assert client.read_holding_registers(rm.STATUS + 1, 1) == [rm.READY | rm.IN_POS]  # the lower word alone
    assert int32(rm.POSITION) == 3600
    beyond = halves(0, rm.ABSOLUTE, 40_000, 4000)  # a target beyond the drive's limit
    assert client.write_multiple_registers(rm.DATA_NO, beyond)
    assert client.write_multiple_registers(rm.TRIGGER, halves(rm.TRIGGER_ALL))
    assert int32(rm.ALARM_CODE) == rm.ALARM_OVERTRAVEL
    assert int32(rm.STATUS) & rm.ALARM
    for value in (1, 0):
        assert client.write_multiple_registers(rm.MAINTENANCE_ALARM_RESET, halves(value))
    assert int32(rm.ALARM_CODE) == 0
    for value in (1, 0):
        assert client.write_single_register(rm.COMMAND + 1, rm.STOP * value)  # a pulsed STOP, lower word
    assert srv.stage.command == 0
    for value in (1, 0):
        assert client.write_multiple_registers(rm.MAINTENANCE_P_PRESET, halves(value))
    assert int32(rm.POSITION) == 0
    assert int32(rm.STATUS) & rm.HOME_END
    assert not client.write_multiple_registers(rm.MAINTENANCE_ALARM_RESET, halves(2))
    assert client.last_except == 3
    client.close()


def test_ten_thousand_broken_frames_leave_the_server_answering(server, caplog, capfd):
    """Random bytes, requests of every function code with random fields (to units that are there and
    one that is not), truncated and bit-flipped frames: each broken one on a connection of its own (a
    broken MBAP header leaves a stream no device can resynchronise), the well-formed ones on one
    connection, each answered. Afterwards a fresh client reads the status, and no traceback was logged
    or printed."""
    _, host, port = server
    rng = random.Random(14)
    steady = socket.create_connection((host, port), timeout=2)
    answered = 0
    with caplog.at_level(logging.WARNING):
        for k in range(10_000):
            pdu = bytes([rng.choice([1, 2, 3, 4, 5, 6, 8, 15, 16, 17, 23, 43, 0x41, 0x7F])]) + rng.randbytes(
                rng.choice([4, 4, 4, rng.randint(0, 12)])
            )
            frame = bytearray(struct.pack(">HHHB", k, 0, len(pdu) + 1, rng.choice([0, 1, 2, 9])) + pdu)
            how = k % 4
            if how == 1:
                steady.sendall(bytes(frame))
                reply = steady.recv(512)
                assert reply[:2] == frame[:2], (frame.hex(" "), reply.hex(" "))  # its own answer
                answered += 1
                continue
            if how == 0:
                frame = bytearray(rng.randbytes(rng.randint(1, 20)))
            elif how == 2:
                frame = frame[: rng.randint(1, len(frame) - 1)]
            else:
                frame[rng.randrange(len(frame))] ^= 1 << rng.randrange(8)
            with socket.create_connection((host, port), timeout=2) as broken:
                broken.sendall(bytes(frame))
    steady.close()
    status = ask(host, port, rm.STAGE_UNIT, bytes([3, 0, rm.STATUS, 0, 2]))
    assert status[:2] == bytes([3, 4])
    assert answered == 2_500
    assert "Traceback" not in caplog.text
    assert "Traceback" not in capfd.readouterr().err


def test_an_rtu_client_of_its_own_moves_the_stage_switches_the_lamp_and_hears_the_exceptions():
    """minimalmodbus over the simulated serial line (115 200 Bd on a pty), as lab scripts drive Oriental
    Motor drives: its own RTU framing, CRC and timing. A direct data operation in one write, the status and
    position as 32-bit big-endian reads, the lamp's coil; an address beyond the map is an illegal data
    address (exception 2), and a unit that is not on the line stays silent (RTU has no gateway to answer
    for it)."""
    with TurntableServer.simulated(speed_factor=50.0) as srv:
        path = srv.serve_rtu()

        def on_line(unit: int) -> minimalmodbus.Instrument:
            instrument = minimalmodbus.Instrument(path, unit, close_port_after_each_call=True)
            port = instrument.serial
            assert port is not None  # open until each call closes it
            port.baudrate, port.timeout = 115_200, 2.0  # s: a loaded machine, not the line, is slow
            return instrument

        stage, relay = on_line(rm.STAGE_UNIT), on_line(rm.RELAY_UNIT)
        assert stage.read_long(rm.STATUS, signed=True) & rm.READY
        operation = [w for v in (0, rm.ABSOLUTE, -2500, 4000, 1_000_000, 1_000_000, 1000, rm.TRIGGER_ALL)
                     for w in struct.unpack(">HH", struct.pack(">i", v))]  # fmt: skip
        stage.write_registers(rm.DATA_NO, operation)
        deadline = time.monotonic() + 10
        while stage.read_long(rm.STATUS, signed=True) & rm.MOVE:
            assert time.monotonic() < deadline
        assert stage.read_long(rm.POSITION, signed=True) == -2500
        assert srv.stage.moves == [-2500]
        relay.write_bit(rm.LAMP_COIL, 1, functioncode=5)
        assert srv.stage.lamp
        assert relay.read_bit(rm.LAMP_COIL, functioncode=1) == 1
        relay.write_bit(rm.LAMP_COIL, 0, functioncode=5)
        assert not srv.stage.lamp
        with pytest.raises(minimalmodbus.IllegalRequestError):
            stage.read_registers(200, 2)
        with pytest.raises(minimalmodbus.NoResponseError):
            on_line(9).read_register(rm.STATUS)


def test_libmodbus_mbpoll_moves_the_stage_and_switches_the_lamp_over_tcp_and_rtu():
    """mbpoll, the command-line master of libmodbus (the C library much SCADA software uses): a direct
    data operation written as 32-bit big-endian values, the position and status read back as such, the
    lamp's coil; over TCP a unit that is not there is "Target device failed to respond" (0x0B, from the
    gateway), over RTU a timeout (the line stays silent), and an address beyond the map "Illegal data
    address" on both."""
    if not shutil.which("mbpoll"):
        pytest.fail("mbpoll is missing: scripts/setup installs it (Debian: apt-get install mbpoll)")
    with TurntableServer.simulated(speed_factor=50.0) as srv:
        host, port = srv.serve_tcp()
        line = srv.serve_rtu()
        tcp = ["-m", "tcp", "-p", str(port)]
        rtu = ["-m", "rtu", "-b", "115200", "-P", "none"]

        def mbpoll(link: list[str], unit: int, address: int, kind: str, *values: int, count: int = 1):
            """One mbpoll call (0-based ``address``): its output and exit status; reads without values."""
            args = ["mbpoll", *link, "-a", str(unit), "-0", "-r", str(address), "-t", kind, "-B", "-o", "2"]
            args += [host if link is tcp else line]
            args += [str(v) for v in values] if values else ["-c", str(count), "-1"]
            done = subprocess.run(args, capture_output=True, text=True, timeout=60, check=False)
            return done.stdout + done.stderr, done.returncode

        def read(link: list[str], unit: int, address: int, kind: str = "4:int") -> int:
            out, status = mbpoll(link, unit, address, kind)
            assert status == 0, out
            found = re.search(rf"^\[{address}\]:\s+(-?\d+)", out, re.MULTILINE)
            assert found is not None, out
            return int(found.group(1))

        operation = (0, rm.ABSOLUTE, 2500, 4000, 1_000_000, 1_000_000, 1000, rm.TRIGGER_ALL)
        out, status = mbpoll(tcp, rm.STAGE_UNIT, rm.DATA_NO, "4:int", *operation)
        assert status == 0, out
        deadline = time.monotonic() + 10
        while read(tcp, rm.STAGE_UNIT, rm.STATUS) & rm.MOVE:
            assert time.monotonic() < deadline
        assert srv.stage.moves == [2500]
        for link in (tcp, rtu):
            assert read(link, rm.STAGE_UNIT, rm.POSITION) == 2500
            assert read(link, rm.STAGE_UNIT, rm.STATUS) & rm.READY
        assert mbpoll(tcp, rm.RELAY_UNIT, rm.LAMP_COIL, "0", 1)[1] == 0
        assert srv.stage.lamp
        assert read(rtu, rm.RELAY_UNIT, rm.LAMP_COIL, "0") == 1
        for link, said in ((tcp, "Target device failed to respond"), (rtu, "Connection timed out")):
            out, status = mbpoll(link, 9, rm.STATUS, "4")
            assert status != 0, out
            assert said in out, out
            out, status = mbpoll(link, rm.STAGE_UNIT, 200, "4", count=2)
            assert status != 0, out
            assert "Illegal data address" in out, out
