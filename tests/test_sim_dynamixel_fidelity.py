"""The simulated servos behave as the ROBOTIS e-manual says a real X-series servo does, seen through the
real dynamixel_sdk on the simulator's pseudo-terminal, the way ROBOTIS's own example programs use it
(ping, group reads of any size, Clear Multi-Turn, the one-turn reset, indirect addresses, velocity
mode, baud rate / protocol type / secondary ID), and through a Protocol 2.0 client written apart from
it (dynamixel-python); and the bus survives whatever bytes it is sent."""

from __future__ import annotations

import logging
import random
import time

import pytest
from dynamixel_sdk import (
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
)

from drivers.dynamixel import UrlPortHandler
from sim.dynamixel.bus import CLIENT_REPLY_TIMEOUT_MS, INTER_BYTE_TIMEOUT_S, SimBus
from sim.dynamixel.protocol import HEADER, Error, crc16, instruction_packet, status_packet

TORQUE, MODE, HOMING, BUS_WATCHDOG, GOAL_VELOCITY, GOAL, MOVING, PRESENT_VELOCITY, PRESENT = (
    64,
    11,
    20,
    98,
    104,
    116,
    122,
    128,
    132,
)
POSITION_MODE, EXTENDED_MODE, VELOCITY_MODE = 3, 4, 1


def _sdk_at(speed_factor: float):
    """Two servos on a pty whose time runs ``speed_factor`` × real time, the SDK at 57 600 baud (the
    factory setting ROBOTIS's examples use)."""
    bus = SimBus.with_servos([1, 2], speed_factor=speed_factor)
    for s in bus.servos:
        s.table[9] = 0  # no return delay
    port = UrlPortHandler(bus.serve_pty(), CLIENT_REPLY_TIMEOUT_MS)
    assert port.openPort()
    assert port.setBaudRate(57600)
    yield bus, port, PacketHandler(2.0)
    port.closePort()
    bus.close()


@pytest.fixture
def sdk():
    yield from _sdk_at(20.0)


@pytest.fixture
def watchdog_sdk():
    """As ``sdk`` with the bus's time 4× real time: its 2 s watchdog is 0.5 s here, so that a client
    stalled by a busy host (a 0.1 s pause was seen under the suite's load at 20×) does not trip it."""
    yield from _sdk_at(4.0)


def wait_until(condition, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_a_group_read_bigger_than_the_control_table_is_refused_and_the_bus_lives_on(sdk, caplog):
    """FAST SYNC READ, SYNC READ and BULK READ asking up to 65 532 bytes from address 0: each servo
    answers an Access Error without data (the read names addresses that do not exist), never a
    64 KiB reply and never an exception in the bus; pings answer afterwards. (At 4 Mbps: the SDK waits
    as long as such a reply would take to arrive.)"""
    bus, port, ph = sdk
    assert port.setBaudRate(4_000_000)  # (the servos hear any speed until their Baud Rate is written)
    for length in (32763, 32764, 65532):
        for fast in (False, True):
            reader = GroupSyncRead(port, ph, 0, length)
            reader.addParam(1)
            reader.addParam(2)
            reader.fastSyncRead() if fast else reader.txRxPacket()  # (the SDK's verdict on a short reply varies)
        bulk = GroupBulkRead(port, ph)
        bulk.addParam(1, 0, length)
        bulk.txRxPacket()
        port.clearPort()
        assert ph.ping(port, 1)[1:] == (COMM_SUCCESS, 0)
    # what the servo answers such a read: its status packet, an Access Error and no data
    reply = bus.handle(
        bytes(
            instruction_packet(
                0xFE, 0x82, (0).to_bytes(2, "little") + (65532).to_bytes(2, "little") + b"\x01"
            )
        )
    )
    assert reply == status_packet(1, Error.ACCESS)
    _, result, error = ph.readTxRx(port, 1, 600, 100)
    assert (result, error) == (COMM_SUCCESS, Error.ACCESS)
    assert "Traceback" not in caplog.text


def test_a_partial_packet_is_dropped_after_the_inter_byte_timeout(sdk):
    """A header declaring 1024 bytes, then silence: the next ping is answered (on a real servo, and now
    here, the partial packet is dropped after a few ms of silence), across reconnections too."""
    bus, port, ph = sdk
    for declared in (1024, 200):
        port.writePort(HEADER + b"\x01" + declared.to_bytes(2, "little") + b"\x02\x00")
        wait_until(lambda: len(bus._reader._buf) > 0)  # the bus holds the partial packet
        time.sleep(3 * INTER_BYTE_TIMEOUT_S)
        answered = sum(ph.ping(port, 1)[1] == COMM_SUCCESS for _ in range(5))
        assert answered == 5


def test_clear_multi_turn_after_a_stop_resets_present_position(sdk):
    """Extended position mode, moved past a turn, stopped (torque off): Clear Multi-Turn succeeds and
    Present Position comes back within one turn; refused only while the axis really moves."""
    _, port, ph = sdk
    assert ph.write1ByteTxRx(port, 1, MODE, EXTENDED_MODE) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, 112, 3) == (COMM_SUCCESS, 0)  # slow: ~1 s on the way
    assert ph.write1ByteTxRx(port, 1, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, GOAL, 6000) == (COMM_SUCCESS, 0)
    assert ph.clearMultiTurn(port, 1) == (COMM_SUCCESS, Error.RESULT_FAIL)  # still on its way
    wait_until(lambda: ph.read4ByteTxRx(port, 1, PRESENT)[0] == 6000)
    assert ph.write1ByteTxRx(port, 1, TORQUE, 0) == (COMM_SUCCESS, 0)
    assert ph.clearMultiTurn(port, 1) == (COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 1, PRESENT)[0] == 6000 % 4096


def test_position_mode_brings_present_position_within_one_turn(sdk):
    """The e-manual's note on Present Position: 6000 in extended mode reads 1904 once Operating Mode is
    changed to Position Control, and a goal of 2048 then moves 144 ticks, not a turn back; with a Homing
    Offset the reset applies to the offset reading. The change of mode also resets the profile."""
    bus, port, ph = sdk
    ph.write1ByteTxRx(port, 1, MODE, EXTENDED_MODE)
    ph.write4ByteTxRx(port, 1, 112, 50)  # profile velocity
    ph.write1ByteTxRx(port, 1, TORQUE, 1)
    ph.write4ByteTxRx(port, 1, GOAL, 6000)
    wait_until(lambda: ph.read4ByteTxRx(port, 1, PRESENT)[0] == 6000)
    ph.write1ByteTxRx(port, 1, TORQUE, 0)
    assert ph.write1ByteTxRx(port, 1, MODE, POSITION_MODE) == (COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 1, PRESENT)[0] == 1904
    assert ph.read4ByteTxRx(port, 1, 112)[0] == 0  # profile velocity reset with the mode
    ph.write1ByteTxRx(port, 1, TORQUE, 1)
    ph.write4ByteTxRx(port, 1, GOAL, 2048)
    wait_until(lambda: ph.read4ByteTxRx(port, 1, PRESENT)[0] == 2048)
    servo = bus.servo(1)
    assert abs(servo._profile.goal - servo._profile.start) == 144
    # torque switched on in position mode resets too, Homing Offset applied
    ph.write1ByteTxRx(port, 2, TORQUE, 0)
    ph.write4ByteTxRx(port, 2, HOMING, 1000)
    bus.servo(2)._profile.start = bus.servo(2)._profile.goal = 3500.0  # turned by hand: reads 4500
    assert ph.read4ByteTxRx(port, 2, PRESENT)[0] == 4500
    ph.write1ByteTxRx(port, 2, TORQUE, 1)
    assert ph.read4ByteTxRx(port, 2, PRESENT)[0] == 4500 % 4096


def test_indirect_addresses_carry_a_goal_and_the_led_and_read_moving_and_position(sdk):
    """As ROBOTIS's indirect-address example: Goal Position (4 bytes) and LED behind Indirect Data 1–5,
    Moving and Present Position behind Indirect Data 6–10; one sync write moves the axis and lights the
    LED, one sync read returns where it is. Indirect Address takes only the RAM area (64–661); a
    multi-byte field is written whole. The feedforward gains and the bus watchdog are writable."""
    bus, port, ph = sdk
    targets = [GOAL, GOAL + 1, GOAL + 2, GOAL + 3, 65, MOVING, PRESENT, PRESENT + 1, PRESENT + 2, PRESENT + 3]
    for k, target in enumerate(targets):
        assert ph.write2ByteTxRx(port, 1, 168 + 2 * k, target) == (COMM_SUCCESS, 0)
    assert ph.write2ByteTxRx(port, 1, 168, 30)[1] == Error.DATA_RANGE  # EEPROM: not indirect-able
    ph.write1ByteTxRx(port, 1, TORQUE, 1)
    writer = GroupSyncWrite(port, ph, 224, 5)
    writer.addParam(1, [*(3000).to_bytes(4, "little"), 1])
    assert writer.txPacket() == COMM_SUCCESS
    assert ph.read1ByteTxRx(port, 1, 65)[0] == 1
    assert [g.goal for g in bus.goals] == [3000]
    reader = GroupSyncRead(port, ph, 229, 5)
    reader.addParam(1)

    def there() -> bool:
        assert reader.txRxPacket() == COMM_SUCCESS
        return reader.getData(1, 229, 1) == 0 and reader.getData(1, 230, 4) == 3000

    wait_until(there)
    assert ph.write1ByteTxRx(port, 1, 224, 5)[1] == Error.DATA_LENGTH  # one byte of Goal Position
    for address, size, value in ((88, 2, 120), (90, 2, 300), (98, 1, 50)):
        assert ph.writeTxRx(port, 1, address, size, list(value.to_bytes(size, "little"))) == (COMM_SUCCESS, 0)
        assert ph.readTxRx(port, 1, address, size)[0] == list(value.to_bytes(size, "little"))


def test_velocity_mode_turns_at_goal_velocity(sdk):
    _, port, ph = sdk
    ph.write1ByteTxRx(port, 1, MODE, VELOCITY_MODE)
    ph.write1ByteTxRx(port, 1, TORQUE, 1)
    start = ph.read4ByteTxRx(port, 1, PRESENT)[0]
    assert ph.write4ByteTxRx(port, 1, GOAL_VELOCITY, 100) == (COMM_SUCCESS, 0)
    time.sleep(0.2)
    assert ph.read4ByteTxRx(port, 1, PRESENT_VELOCITY)[0] == 100
    assert ph.read1ByteTxRx(port, 1, MOVING)[0] == 1
    assert ph.read4ByteTxRx(port, 1, PRESENT)[0] > start + 100
    assert ph.write4ByteTxRx(port, 1, GOAL_VELOCITY, 300)[1] == Error.DATA_LIMIT  # above Velocity Limit (200)
    ph.write4ByteTxRx(port, 1, GOAL_VELOCITY, 0)
    assert ph.read4ByteTxRx(port, 1, PRESENT_VELOCITY)[0] == 0


def test_the_bus_watchdog_stops_a_servo_the_bus_left_alone(watchdog_sdk):
    """The e-manual's Bus Watchdog example: turning in velocity mode, Bus Watchdog 100 (2 s of the
    servo's time); while packets keep coming nothing happens; 2 s of silence stop the axis where it was
    then, Bus Watchdog reads −1 and a new Goal Velocity is a Data Range Error until Bus Watchdog is
    written 0, after which the goal is obeyed again."""
    _, port, ph = watchdog_sdk  # the bus's time runs 4× real time: 2 s of it are 0.5 s here
    ph.write1ByteTxRx(port, 1, MODE, VELOCITY_MODE)
    ph.write1ByteTxRx(port, 1, TORQUE, 1)
    assert ph.write4ByteTxRx(port, 1, GOAL_VELOCITY, 50) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, BUS_WATCHDOG, 100) == (COMM_SUCCESS, 0)
    for _ in range(15):  # 0.3 s of reads 20 ms apart: never 2 s of the bus's time (0.5 s) without a packet
        assert ph.read1ByteTxRx(port, 1, BUS_WATCHDOG)[0] == 100
        time.sleep(0.02)
    before = ph.read4ByteTxRx(port, 1, PRESENT)[0]
    time.sleep(1.0)  # 4 s of the bus's time in silence
    assert ph.read1ByteTxRx(port, 1, BUS_WATCHDOG)[0] == 0xFF  # −1: Bus Watchdog Error
    stopped = ph.read4ByteTxRx(port, 1, PRESENT)[0]
    travel = 50 * 0.229 / 60 * 4096 * 2.0  # 2 s at goal velocity 50 after the last packet
    assert stopped - before == pytest.approx(travel, rel=0.05)  # (5 %: the read's own time on the line)
    assert ph.read4ByteTxRx(port, 1, PRESENT_VELOCITY)[0] == 0
    assert ph.read1ByteTxRx(port, 1, TORQUE)[0] == 1  # torque stays on
    assert ph.write4ByteTxRx(port, 1, GOAL_VELOCITY, 150)[1] == Error.DATA_RANGE
    assert ph.write4ByteTxRx(port, 1, GOAL, 0)[1] == Error.DATA_RANGE
    assert ph.write1ByteTxRx(port, 1, BUS_WATCHDOG, 0xFF)[1] == Error.DATA_RANGE  # −1 is the servo's to set
    assert ph.write1ByteTxRx(port, 1, BUS_WATCHDOG, 0) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, GOAL_VELOCITY, 150) == (COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 1, PRESENT_VELOCITY)[0] == 150


def test_firmware_before_v38_has_no_bus_watchdog(sdk):
    """The e-manual adds Bus Watchdog in firmware v38: an older servo refuses a write to it (Access Error,
    an address it does not have) and whatever sits at its address never stops the axis."""
    bus, port, ph = sdk
    servo = bus.servo(1)
    servo.table[6] = 37
    assert ph.write1ByteTxRx(port, 1, BUS_WATCHDOG, 1)[1] == Error.ACCESS
    servo.table[98] = 1  # 20 ms, were it a field
    ph.write1ByteTxRx(port, 1, MODE, VELOCITY_MODE)
    ph.write1ByteTxRx(port, 1, TORQUE, 1)
    assert ph.write4ByteTxRx(port, 1, GOAL_VELOCITY, 50) == (COMM_SUCCESS, 0)
    time.sleep(0.2)  # 4 s of the bus's time in silence
    assert ph.read1ByteTxRx(port, 1, BUS_WATCHDOG)[0] == 1
    assert ph.read4ByteTxRx(port, 1, PRESENT_VELOCITY)[0] == 50


def test_baud_rate_protocol_type_and_secondary_id_take_effect(sdk):
    """After Baud Rate is set to 1 Mbps a servo ignores packets at any other speed (until then it hears
    any: the pty has no speed of its own);
    after Protocol Type 1 it no longer answers Protocol 2.0; a goal sent to its Secondary ID moves it
    without a status packet."""
    bus, port, ph = sdk
    assert ph.write1ByteTxRx(port, 2, 8, 3) == (COMM_SUCCESS, 0)  # 1 Mbps (its reply still at the old speed)
    assert ph.ping(port, 2)[1] == COMM_RX_TIMEOUT
    assert ph.ping(port, 1)[1] == COMM_SUCCESS  # its neighbour still at 57 600
    assert port.setBaudRate(1_000_000)
    assert ph.ping(port, 2)[1] == COMM_SUCCESS
    assert ph.read1ByteTxRx(port, 2, 8)[0] == 3
    assert ph.ping(port, 1)[1] == COMM_SUCCESS  # never set: a pty has no speed, so it hears any
    assert port.setBaudRate(57600)
    assert ph.ping(port, 2)[1] == COMM_RX_TIMEOUT

    assert ph.write1ByteTxRx(port, 1, 12, 7) == (COMM_SUCCESS, 0)  # Secondary ID 7
    ph.write1ByteTxRx(port, 1, TORQUE, 1)
    assert ph.write4ByteTxRx(port, 7, GOAL, 2100)[0] == COMM_RX_TIMEOUT  # obeyed, not answered
    assert [g.goal for g in bus.goals if g.servo_id == 1] == [2100]
    ph.write1ByteTxRx(port, 1, TORQUE, 0)
    assert ph.write1ByteTxRx(port, 1, 13, 1) == (COMM_SUCCESS, 0)  # Protocol 1.0 from now on
    assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT


def test_ten_thousand_random_truncated_and_bit_flipped_packets_leave_the_bus_answering(caplog):
    """Random bytes, whole packets of every instruction with random parameters, truncated and
    bit-flipped ones, fed to the bus (not through a port: 10 000 in a few seconds): the bus never
    raises and logs no traceback, and every servo still speaking Protocol 2.0 (the noise may have
    written its settings, as it would a real servo's) answers a ping at its ID with a well-formed
    status packet afterwards."""
    bus = SimBus.with_servos([1, 2])
    for s in bus.servos:
        s.table[9] = 0
    rng = random.Random(14)
    instructions = [
        0x01,
        0x02,
        0x03,
        0x04,
        0x05,
        0x06,
        0x08,
        0x10,
        0x82,
        0x83,
        0x8A,
        0x92,
        0x93,
        0x9A,
        0x55,
        0x7F,
    ]
    with caplog.at_level(logging.WARNING):
        for k in range(10_000):
            kind = k % 4
            if kind == 0:
                data = bytearray(rng.randbytes(rng.randint(1, 64)))
            else:
                params = rng.randbytes(rng.randint(0, 40))
                data = bytearray(
                    instruction_packet(rng.choice([1, 2, 0xFE, 9]), rng.choice(instructions), params)
                )
                if kind == 2:
                    data = data[: rng.randint(1, len(data))]
                elif kind == 3:
                    data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
            bus.handle(bytes(data))
            if k % 500 == 0:
                time.sleep(2 * INTER_BYTE_TIMEOUT_S)  # now and then the line falls silent
        time.sleep(2 * INTER_BYTE_TIMEOUT_S)
        speaking = [s for s in bus.servos if s.get("protocol_type") == 2]
        assert speaking, "the noise silenced every servo: choose another seed"
        for s in speaking:
            reply = bus.handle(
                instruction_packet(s.id, 0x01)
            )  # (two servos the noise gave one ID both answer)
            first = reply[: 7 + int.from_bytes(reply[5:7], "little")]
            assert first[:5] == HEADER + bytes([s.id]), reply.hex()
            assert first[7] == 0x55
            assert crc16(first[:-2]) == int.from_bytes(first[-2:], "little")
    assert "Traceback" not in caplog.text


def test_a_protocol_2_client_written_apart_from_the_sdk_drives_the_servos():
    """dynamixel-python (``dxl2``: its own packets, CRC, byte stuffing and status parsing, nothing of
    dynamixel-sdk) at 1 Mbaud: ping and broadcast ping (an XM430-W350, model 1020), read and write, a goal
    beyond the limit (Data Limit Error, 6) and a write to the model number (Access Error, 7), sync write
    and read, fast sync read, bulk write and read, fast bulk read."""
    from dxl2 import v2

    bus = SimBus.with_servos([1, 2], speed_factor=20.0)
    # its timeout is per byte of a header (no servo 3 takes 4 of them) and ends a broadcast ping: the
    # simulated rig's reply timeout, the servos being threads of a busy process
    servos = v2.MotorBus(bus.serve_pty(), baudrate=1_000_000, timeout=CLIENT_REPLY_TIMEOUT_MS / 1000)
    servos.connect()
    try:
        xm430 = {"model_number": 1020, "firmware_version": bus.servos[0].table[6]}
        assert servos.ping(1).data == xm430
        assert servos.ping(3).timeout  # no servo 3 on the bus
        assert servos.broadcast_ping().data == {1: xm430, 2: xm430}
        goal, present, torque, led = 116, 132, 64, 65
        assert servos.write(1, torque, 1, 1).ok
        assert servos.write(1, goal, 4, 2300).ok
        assert servos.read(1, goal, 4).data == 2300
        assert servos.write(1, goal, 4, 99_999).error == Error.DATA_LIMIT  # past Max Position Limit
        assert servos.write(1, 0, 2, 5).error == Error.ACCESS  # Model Number is read-only
        wait_until(lambda: servos.read(1, present, 4, signed=True).data == 2300)
        goals = v2.SyncParams(goal, 4)
        goals.add_value(1, 2100)
        goals.add_value(2, 1900)
        assert servos.write(2, torque, 1, 1).ok
        servos.sync_write(goals)
        positions = v2.SyncParams(present, 4, signed=True)
        positions.add_motor(1)
        positions.add_motor(2)
        wait_until(lambda: servos.sync_read(positions).data == [2100, 1900])
        assert servos.fast_sync_read(positions, signed=True).data == [2100, 1900]
        writes = v2.BulkParams()
        writes.add_value(1, led, 1, 1)
        writes.add_value(2, goal, 4, 2000)
        servos.bulk_write(writes)
        reads = v2.BulkParams()
        reads.add_address(1, led, 1)
        reads.add_address(2, goal, 4)
        assert servos.bulk_read(reads).data == [1, 2000]
        assert servos.fast_bulk_read(reads).data == [1, 2000]
    finally:
        servos.disconnect()
        bus.close()
