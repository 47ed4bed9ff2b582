"""The gantry driver against the simulated bus: real dynamixel-sdk bytes over a pseudo-terminal."""

import pytest

from drivers.dynamixel import Axis, DynamixelGantry, GantryConfig
from drivers.errors import DeviceError, DeviceFault, DeviceTimeout, HardwareAlarm, LimitError, SettleTimeout
from drivers.protocols import Positioner
from sim.dynamixel.bus import CLIENT_REPLY_TIMEOUT_MS, SimBus
from sim.dynamixel.servo import OVERLOAD

AXES = (Axis(1, 1024, 3072, "azimuth"), Axis(2, 1024, 2048, "elevation"))


@pytest.fixture
def bus():
    with SimBus.with_servos([1, 2], speed_factor=40.0) as b:
        yield b


def gantry_on(bus, url=None, **kw) -> DynamixelGantry:
    config = {"retries": 2, "backoff_s": 0.001, "reply_timeout_ms": CLIENT_REPLY_TIMEOUT_MS} | kw
    return DynamixelGantry(GantryConfig(url or bus.serve_pty(), AXES, **config))


def test_the_wait_for_a_reply_is_the_configured_one_not_the_sdks(bus):
    """A reply 0.1 s late is lost to the SDK's 34 ms wait and read within a 300 ms one."""
    bus.fault(1).delay_s = 0.1
    with pytest.raises(DeviceTimeout, match="no reply"):
        gantry_on(bus, retries=0, reply_timeout_ms=34).connect()
    assert gantry_on(bus, retries=0, reply_timeout_ms=300).connect()[1] == "XM430-W350"


def test_connect_configures_and_verifies(bus):
    bus.servo(1).table[64] = 1  # torque already on: the driver must switch it off before EEPROM writes
    g = gantry_on(bus)
    assert isinstance(g, Positioner)
    assert g.connect() == {1: "XM430-W350", 2: "XM430-W350"}
    for s, axis in zip(bus.servos, AXES, strict=True):
        assert s.get("operating_mode") == 3
        assert s.get("return_delay_time") == 0
        assert (s.get("min_position_limit"), s.get("max_position_limit")) == (axis.min_ticks, axis.max_ticks)
        assert s.get("torque_enable") == 1
    g.close()
    assert all(s.get("torque_enable") == 0 for s in bus.servos)  # safe on exit


def test_move_and_settle_with_one_sync_write(bus):
    g = gantry_on(bus)
    g.connect()
    g.move_to((2500, 1800))
    assert g.wait_settled(timeout_s=5) == pytest.approx((2500, 1800), abs=2)
    assert [(r.servo_id, r.goal) for r in bus.goals] == [(1, 2500), (2, 1800)]
    g.close()


def test_goals_outside_the_limits_are_never_sent(bus):
    g = gantry_on(bus)
    g.connect()
    with pytest.raises(LimitError, match=r"elevation.*outside \[1024, 2048\]"):
        g.move_to((2000, 3000))
    assert bus.goals == []  # nothing reached the bus
    g.close()


def test_link_faults_are_retried_then_reported(bus):
    g = gantry_on(bus)
    g.connect()
    bus.fault(2).drop_replies = 1
    assert len(g.position()) == 2
    bus.fault(1).corrupt_replies = 1
    assert len(g.position()) == 2
    assert g.retried == 2  # one retry each
    bus.fault(1).drop_replies = 10
    with pytest.raises(DeviceTimeout, match="azimuth"):
        g.position()
    g.close(torque_off=False)


def test_hardware_alarm_at_connect_needs_permission_to_reboot(bus):
    bus.servo(2).hardware_fault(OVERLOAD)
    with pytest.raises(HardwareAlarm, match=r"overload.*allow a reboot") as err:
        gantry_on(bus).connect()
    assert err.value.status == OVERLOAD
    g = gantry_on(bus, reboot_on_alarm=True)
    g.connect()  # rebooted, then configured
    assert bus.servo(2).get("hardware_error_status") == 0
    g.close()


def test_overload_and_stuck_axis_during_a_move(bus):
    g = gantry_on(bus)
    g.connect()
    bus.servo(1).stuck = True
    g.move_to((2600, 1500))
    with pytest.raises(SettleTimeout, match=r"azimuth at 2048 \(goal 2600\)"):
        g.wait_settled(timeout_s=0.3)
    bus.servo(1).stuck = False
    bus.servo(2).hardware_fault(OVERLOAD)
    with pytest.raises(HardwareAlarm, match=r"elevation.*overload"):
        g.wait_settled(timeout_s=1)
    g.close()


def test_device_refusals_become_faults(bus):
    bad = (Axis(1, 0, 5000, "azimuth"), AXES[1])  # the servo's limit range ends at 4095
    g = DynamixelGantry(
        GantryConfig(bus.serve_pty(), bad, retries=0, reply_timeout_ms=CLIENT_REPLY_TIMEOUT_MS)
    )
    with pytest.raises(DeviceFault, match="data range error") as err:
        g.connect()
    assert err.value.code == 4
    g.close()


def test_socket_url_and_unopenable_port(bus):
    g = gantry_on(bus, url=bus.serve_tcp())
    assert g.connect()
    g.close()
    with pytest.raises(DeviceError, match="cannot open the port"):
        DynamixelGantry(GantryConfig("/dev/does-not-exist", AXES))


def test_park_confirms_torque_off_even_after_a_transaction_was_cut_short(bus):
    """An exception in the middle of an SDK exchange (a signal, say) leaves dynamixel-sdk's port marked
    busy, after which every exchange fails with "Port is in use!". The safe-state step frees it, switches
    the torque off, and says so only because the servos read back 0."""
    g = gantry_on(bus)
    g.connect()
    g.move_to((2000, 1500))
    g.port.is_using = True  # what an interrupted txRxPacket leaves behind
    assert g.park() == "torque off (read back)"
    assert all(s.get("torque_enable") == 0 for s in bus.servos)
    g.release()


def test_park_names_the_servo_that_does_not_answer(bus):
    g = gantry_on(bus)
    g.connect()
    bus.fault(2).drop_replies = 1000
    with pytest.raises(DeviceError, match=r"could not switch torque off \(elevation: no reply to write 64"):
        g.park(attempts=2)
    assert bus.servo(1).get("torque_enable") == 0  # the other axis is still made safe
    g.release()


def test_a_servo_in_overload_confirms_its_torque_off(bus):
    g = gantry_on(bus)
    g.connect()
    bus.servo(2).hardware_fault(OVERLOAD)  # it answers every packet with the alert bit from now on
    assert g.park() == "torque off (read back)"
    g.release()


def test_a_servo_left_past_a_turn_is_moved_the_short_way(bus):
    """A servo another program left in Extended Position mode at 6000 ticks (a turn and a half): the
    driver's switch to Position Control mode brings Present Position within one turn, as the e-manual
    says a real servo does (1904), and the first move to 2048 goes 144 ticks, not 3952 back round."""
    servo = bus.servo(1)
    servo.table[11] = 4  # extended position mode
    servo._profile.start = servo._profile.goal = 6000.0
    assert servo.present_position() == 6000
    g = gantry_on(bus)
    g.connect()
    assert g.position()[0] == 1904
    g.move_to((2048, 1500))
    assert g.wait_settled(timeout_s=5)[0] == pytest.approx(2048, abs=2)
    assert abs(servo._profile.goal - servo._profile.start) == pytest.approx(144, abs=2)
    g.close()


def test_a_bus_watchdog_left_on_or_expired_is_cleared_at_connect(bus):
    """Another program left servo 1's bus watchdog expired (−1: goals refused) and servo 2's on at 40 ms
    (it would stop the axis in the first exposure longer than that): connect turns both off and moves
    work; firmware older than v38 has no watchdog and is not written."""
    bus.servo(1).table[98] = 0xFF  # −1
    bus.servo(2).table[98] = 2
    g = gantry_on(bus)
    g.connect()
    assert [s.get("bus_watchdog") for s in bus.servos] == [0, 0]
    g.move_to((2500, 1800))
    assert g.wait_settled(timeout_s=5) == pytest.approx((2500, 1800), abs=2)
    g.close()
    with SimBus.with_servos([1, 2], speed_factor=40.0) as old:
        for servo in old.servos:
            servo.table[6] = 37  # firmware v37
            servo.table[98] = 3  # not a field there: a write would be refused, and it never expires
        g = gantry_on(old)
        g.connect()
        assert [s.table[98] for s in old.servos] == [3, 3]
        g.close()
