"""The simulated Dynamixel bus: byte-exact against the ROBOTIS e-manual, and driven by the real SDK."""

import time

import numpy as np
import pytest
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
)

from drivers.dynamixel import UrlPortHandler
from sim.dynamixel.bus import CLIENT_REPLY_TIMEOUT_MS, SimBus
from sim.dynamixel.control_table import ACCELERATION_UNIT_TICKS_PER_S2, VELOCITY_UNIT_TICKS_PER_S
from sim.dynamixel.protocol import Error, PacketReader, crc16, frame, instruction_packet, stuff, unstuff
from sim.dynamixel.servo import OVERLOAD, SimServo

H = bytes.fromhex


def manual_bus() -> SimBus:
    """Two XM430-W210 (model 1030, firmware 38) as in the e-manual's examples."""
    bus = SimBus.with_servos([1, 2], model_number=1030, firmware=38)
    for s in bus.servos:
        s.table[9] = 0  # no return delay
    return bus


# (instruction packet, expected reply), copied from the ROBOTIS e-manual "Protocol 2.0"
MANUAL = [
    ("ping", "FF FF FD 00 01 03 00 01 19 4E", "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"),
    (
        "broadcast ping",
        "FF FF FD 00 FE 03 00 01 31 42",
        "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D",
    ),
    ("write goal 512", "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89", "FF FF FD 00 01 04 00 55 00 A1 0C"),
    ("reg write", "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E", "FF FF FD 00 01 04 00 55 00 A1 0C"),
    ("action", "FF FF FD 00 01 03 00 05 02 CE", "FF FF FD 00 01 04 00 55 00 A1 0C"),
    ("factory reset", "FF FF FD 00 01 04 00 06 01 A1 E6", "FF FF FD 00 01 04 00 55 00 A1 0C"),
    ("reboot", "FF FF FD 00 01 03 00 08 2F 4E", "FF FF FD 00 01 04 00 55 00 A1 0C"),
    ("clear", "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC", "FF FF FD 00 01 04 00 55 00 A1 0C"),
]


@pytest.mark.parametrize(("what", "sent", "reply"), MANUAL, ids=[m[0] for m in MANUAL])
def test_manual_packets_byte_for_byte(what, sent, reply):
    bus = manual_bus()
    if what == "action":  # the manual's condition: a reg write is already registered
        bus.handle(H(MANUAL[3][1]))
    assert crc16(H(sent)[:-2]) == int.from_bytes(H(sent)[-2:], "little")
    assert bus.handle(H(sent)) == H(reply)


def test_manual_reads():
    bus = manual_bus()
    bus.servo(1)._profile.start = bus.servo(1)._profile.goal = 166
    bus.servo(2)._profile.start = bus.servo(2)._profile.goal = 2079
    read = "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15"
    assert bus.handle(H(read)) == H("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")
    sync_read = "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA"
    assert bus.handle(H(sync_read)) == H(
        "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE"
    )
    bus.servo(1).input_voltage_dv = 119
    bus.servo(2).temperature_c = 36
    bulk_read = "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05"
    assert bus.handle(H(bulk_read)) == H(
        "FF FF FD 00 01 06 00 55 00 77 00 C3 69 FF FF FD 00 02 05 00 55 00 24 8B A9"
    )


def test_manual_group_writes():
    bus = manual_bus()
    assert bus.handle(H("FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87")) == b""
    assert [(g.servo_id, g.goal) for g in bus.goals] == [(1, 150), (2, 170)]
    assert bus.handle(H("FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68")) == b""
    assert bus.servo(1).get("max_voltage_limit") == 160
    assert bus.servo(2).get("temperature_limit") == 80


def test_stuffing_round_trip_and_lenient_parsing():
    body = bytes([0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00])
    assert stuff(body) == bytes([0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00])
    assert unstuff(stuff(body)) == body
    assert unstuff(body) == body  # an unstuffed pattern is left alone
    stuffed = instruction_packet(1, 0x03, body[1:])
    unstuffed = frame(1, body, stuffed=False)  # what dynamixel-sdk 4.1.0 sends
    for raw in (stuffed, unstuffed):
        (p,) = PacketReader().feed(raw)
        assert p.crc_ok
        assert p.params == body[1:]


def test_header_search_skips_noise_and_reassembles():
    reader = PacketReader()
    ping = H("FF FF FD 00 01 03 00 01 19 4E")
    noise = bytes([0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x13, 0xFF])  # includes a stuffed pseudo-header
    packets = []
    for byte in noise + ping + ping[:4]:
        packets += reader.feed(bytes([byte]))
    packets += reader.feed(ping[4:])
    assert [(p.id, p.instruction, p.crc_ok) for p in packets] == [(1, 1, True), (1, 1, True)]


@pytest.mark.parametrize(
    ("address", "data", "torque", "error"),
    [
        (0, b"\x00\x00", 0, Error.ACCESS),  # model number is read-only
        (11, b"\x01", 1, Error.ACCESS),  # EEPROM locked while torque is on
        (116, (5000).to_bytes(4, "little"), 0, Error.DATA_LIMIT),  # beyond the max position limit
        (64, b"\x02", 0, Error.DATA_RANGE),
        (11, b"\x02", 0, Error.DATA_RANGE),  # not an operating mode
        (116, b"\x00\x02", 0, Error.DATA_LENGTH),  # half a goal position
        (14, b"\x00", 0, Error.ACCESS),  # undefined address
        (146, b"\x00\x00", 0, Error.ACCESS),  # past the table
    ],
)
def test_access_rules(address, data, torque, error):
    bus = manual_bus()
    bus.servo(1).table[64] = torque
    reply = bus.handle(instruction_packet(1, 0x03, address.to_bytes(2, "little") + data))
    assert reply[8] == error


def test_crc_error_and_unknown_instruction_replies():
    bus = manual_bus()
    bad = bytearray(H("FF FF FD 00 01 03 00 01 19 4E"))
    bad[-1] ^= 0xFF
    assert bus.handle(bytes(bad))[8] == Error.CRC
    assert bus.handle(instruction_packet(1, 0x7E))[8] == Error.INSTRUCTION


def test_status_return_level():
    bus = manual_bus()
    s = bus.servo(1)
    s.table[68] = 1
    assert bus.handle(instruction_packet(1, 0x03, bytes([65, 0, 1]))) == b""  # writes go unanswered
    assert bus.handle(instruction_packet(1, 0x02, bytes([65, 0, 1, 0])))[9] == 1
    s.table[68] = 0
    assert bus.handle(instruction_packet(1, 0x02, bytes([65, 0, 1, 0]))) == b""
    assert bus.handle(instruction_packet(1, 0x01)) != b""  # ping always answers


def test_trapezoidal_motion_follows_the_profile():
    """The servo's motion read at chosen instants of its own clock (stepped by the test, so a busy
    machine cannot shift them): ramp up, cruise, ramp down, arriving when the trapezoid says."""
    now = [0.0]
    s = SimServo(1, lambda: now[0])
    bus = SimBus([s])
    s.table[9] = 0
    for address, value, size in ((112, 100, 4), (108, 20, 4), (64, 1, 1)):
        assert (
            bus.handle(
                instruction_packet(1, 0x03, address.to_bytes(2, "little") + value.to_bytes(size, "little"))
            )[8]
            == 0
        )
    bus.handle(instruction_packet(1, 0x03, (116).to_bytes(2, "little") + (3048).to_bytes(4, "little")))
    v, a, d = 100 * VELOCITY_UNIT_TICKS_PER_S, 20 * ACCELERATION_UNIT_TICKS_PER_S2, 1000
    ramp_s = v / a
    expected = 2 * ramp_s + (d - v * ramp_s) / v  # trapezoid: ramp up, cruise, ramp down
    seen = []
    for t in np.linspace(0.0, 1.2 * expected, 241):
        now[0] = float(t)
        seen.append((float(t), s.present_position(), s.get("moving")))
    # the rounded position reads the goal once half a tick is left, sqrt(2 × 0.5 / a) before the end
    arrived = next(t for t, p, _ in seen if p == 3048)
    assert arrived == pytest.approx(expected - (1 / a) ** 0.5, abs=0.006 * expected)  # ≥ the grid's step
    positions = np.array([p for _, p, _ in seen])
    assert np.all(np.diff(positions) >= 0)  # monotonic
    assert all(m == 1 for _, p, m in seen if p < 3048)
    # half-way through the ramp up (t = ramp_s / 2) the axis has covered a t² / 2
    now[0] = ramp_s / 2
    assert s.present_position() - 2048 == pytest.approx(a * (ramp_s / 2) ** 2 / 2, abs=1)
    # the rounded position reaches the goal while the last half tick is still ramping down: the profile
    # must end, and report so, right after
    now[0] = expected + 1e-3
    assert s.present_position() == 3048  # (a read brings the table up to the clock)
    assert s.get("moving") == 0
    assert s.get("moving_status") & 0x01


def test_hardware_error_drops_torque_until_reboot():
    bus = manual_bus()
    s = bus.servo(1)
    s.table[64] = 1
    s.hardware_fault(OVERLOAD)
    reply = bus.handle(instruction_packet(1, 0x02, bytes([70, 0, 1, 0])))
    assert reply[8] & Error.ALERT
    assert reply[9] == OVERLOAD
    assert s.get("torque_enable") == 0
    assert bus.handle(instruction_packet(1, 0x03, bytes([64, 0, 1])))[8] == Error.RESULT_FAIL | Error.ALERT
    bus.handle(instruction_packet(1, 0x08))  # reboot
    assert s.get("hardware_error_status") == 0
    assert bus.handle(instruction_packet(1, 0x03, bytes([64, 0, 1])))[8] == 0


@pytest.fixture
def sdk():
    """The real dynamixel_sdk on the bus's pseudo-terminal."""
    bus = SimBus.with_servos([1, 2], speed_factor=50.0)
    for s in bus.servos:
        s.table[9] = 0
    port = UrlPortHandler(bus.serve_pty(), CLIENT_REPLY_TIMEOUT_MS)
    assert port.openPort()
    assert port.setBaudRate(1_000_000)
    yield bus, port, PacketHandler(2.0)
    port.closePort()
    bus.close()


def test_sdk_ping_read_write(sdk):
    bus, port, ph = sdk
    model, result, error = ph.ping(port, 2)
    assert (model, result, error) == (1020, COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, 112, 200) == (COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 1, 112) == (200, COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, 116, 2500) == (COMM_SUCCESS, 0)
    deadline = time.monotonic() + 2
    while ph.read4ByteTxRx(port, 1, 132)[0] != 2500 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert ph.read4ByteTxRx(port, 1, 132)[0] == 2500
    assert ph.read2ByteTxRx(port, 1, 144) == (120, COMM_SUCCESS, 0)
    result, error = ph.write4ByteTxRx(port, 1, 116, 9000)  # beyond the position limit
    assert (result, error) == (COMM_SUCCESS, Error.DATA_LIMIT)
    assert [g.goal for g in bus.goals] == [2500, 9000]


def test_sdk_group_instructions(sdk):
    bus, port, ph = sdk
    for sid in (1, 2):
        ph.write1ByteTxRx(port, sid, 64, 1)
    writer = GroupSyncWrite(port, ph, 116, 4)
    for sid, goal in ((1, 1000), (2, 3000)):
        writer.addParam(sid, list(goal.to_bytes(4, "little")))
    assert writer.txPacket() == COMM_SUCCESS
    time.sleep(0.3)
    reader = GroupSyncRead(port, ph, 132, 4)
    reader.addParam(1)
    reader.addParam(2)
    assert reader.txRxPacket() == COMM_SUCCESS
    assert (reader.getData(1, 132, 4), reader.getData(2, 132, 4)) == (1000, 3000)
    assert reader.fastSyncRead() == COMM_SUCCESS
    assert (reader.getData(1, 132, 4), reader.getData(2, 132, 4)) == (1000, 3000)
    bulk = GroupBulkRead(port, ph)
    bulk.addParam(1, 146, 1)
    bulk.addParam(2, 132, 4)
    assert bulk.txRxPacket() == COMM_SUCCESS
    assert (bulk.getData(1, 146, 1), bulk.getData(2, 132, 4)) == (33, 3000)
    assert sorted(g.goal for g in bus.goals) == [1000, 3000]


def test_sdk_sends_unstuffed_packets_and_the_bus_still_answers(sdk):
    _, port, ph = sdk
    # 0x00FDFFFF is FF FF FD 00 little-endian: SDK 4.1.0 drops its stuffed copy and sends it raw;
    # the value is out of range, so the servo answers with a data range error — it did parse the packet
    result, error = ph.writeTxRx(port, 1, 116, 4, [0xFF, 0xFF, 0xFD, 0x00])
    assert (result, error) == (COMM_SUCCESS, Error.DATA_RANGE)


def test_sdk_sees_injected_faults(sdk):
    bus, port, ph = sdk
    bus.fault(1).drop_replies = 1
    assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
    bus.fault(1).corrupt_replies = 1
    assert ph.ping(port, 1)[1] == COMM_RX_CORRUPT
    assert ph.ping(port, 1)[1] == COMM_SUCCESS
    bus.servo(2).stuck = True
    ph.write1ByteTxRx(port, 2, 64, 1)
    ph.write4ByteTxRx(port, 2, 116, 3000)
    time.sleep(0.1)
    assert ph.read4ByteTxRx(port, 2, 132)[0] == 2048
    assert ph.read1ByteTxRx(port, 2, 122)[0] == 1  # still "moving": the driver's settle timeout must catch it
    bus.servo(2).hardware_fault(OVERLOAD)
    _, _, error = ph.read1ByteTxRx(port, 2, 70)
    assert error & Error.ALERT


def test_sdk_over_a_socket_url():
    with SimBus.with_servos([1]) as bus:
        bus.servo(1).table[9] = 0
        port = UrlPortHandler(bus.serve_tcp(), CLIENT_REPLY_TIMEOUT_MS)
        assert port.openPort()
        ph = PacketHandler(2.0)
        assert ph.ping(port, 1)[1] == COMM_SUCCESS
        assert ph.write4ByteTxRx(port, 1, 112, 77) == (COMM_SUCCESS, 0)
        assert ph.read4ByteTxRx(port, 1, 112) == (77, COMM_SUCCESS, 0)
        port.closePort()


def test_injected_delay_is_seen_as_a_timeout(sdk):
    bus, port, ph = sdk
    late_s = CLIENT_REPLY_TIMEOUT_MS / 1000 + 0.05  # later than the port waits
    bus.fault(1).delay_s = late_s
    assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
    bus.fault(1).delay_s = 0.0
    time.sleep(late_s)
    port.clearPort()  # the late reply arrived after the timeout: a driver must flush it
    assert ph.ping(port, 1)[1] == COMM_SUCCESS
