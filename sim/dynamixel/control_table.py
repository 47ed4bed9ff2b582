"""The X-series control table (XM430-W350: model 1020; XL430-W250: 1060), as the simulated servo keeps it.

Each field: address, size in bytes, whether it can be written, EEPROM (locked while torque is on) or
RAM, the factory value, the valid range, and signedness. Values travel little-endian. Addresses and
ranges are the ROBOTIS e-manual's (XM430-W350, "Control Table"), including the two blocks of Indirect
Address (168–223, 578–633: 2 bytes each, which control-table address each Indirect Data byte stands
for) and Indirect Data (224–251, 634–661: 1 byte each), which the servo resolves (sim.dynamixel.servo).
"""

from __future__ import annotations

from dataclasses import dataclass

EEPROM_END = 64  # addresses below this are EEPROM: writable only with torque off
TABLE_SIZE = 662  # through Indirect Data 56 (661)
BUS_WATCHDOG_UNIT_S = 0.020
# read-only while the bus watchdog has expired (sim.dynamixel.servo)
GOAL_VALUES = ("goal_pwm", "goal_current", "goal_velocity", "goal_position")
RAM_AREA = (64, 661)  # what an Indirect Address may point at (the e-manual: the RAM area, 64–661)


@dataclass(frozen=True)
class Field:
    name: str
    address: int
    size: int
    writable: bool
    default: int
    low: int = 0
    high: int = 0
    signed: bool = False
    since_firmware: int = 0  # a servo with older firmware has no such field (a write is an Access Error)

    @property
    def end(self) -> int:
        return self.address + self.size


FIELDS = [
    Field("model_number", 0, 2, False, 1020),
    Field("model_information", 2, 4, False, 0),
    Field("firmware_version", 6, 1, False, 48),
    Field("id", 7, 1, True, 1, 0, 252),
    Field("baud_rate", 8, 1, True, 1, 0, 7),
    Field("return_delay_time", 9, 1, True, 250, 0, 254),
    Field("drive_mode", 10, 1, True, 0, 0, 13),
    Field("operating_mode", 11, 1, True, 3, 0, 16),
    Field("secondary_id", 12, 1, True, 255, 0, 255),
    Field("protocol_type", 13, 1, True, 2, 1, 2),
    Field("homing_offset", 20, 4, True, 0, -1_044_479, 1_044_479, True),
    Field("moving_threshold", 24, 4, True, 10, 0, 1023),
    Field("temperature_limit", 31, 1, True, 80, 0, 100),
    Field("max_voltage_limit", 32, 2, True, 160, 95, 160),
    Field("min_voltage_limit", 34, 2, True, 95, 95, 160),
    Field("pwm_limit", 36, 2, True, 885, 0, 885),
    Field("current_limit", 38, 2, True, 1193, 0, 1193),
    Field("velocity_limit", 44, 4, True, 200, 0, 1023),
    Field("max_position_limit", 48, 4, True, 4095, 0, 4095),
    Field("min_position_limit", 52, 4, True, 0, 0, 4095),
    Field("shutdown", 63, 1, True, 52, 0, 255),
    Field("torque_enable", 64, 1, True, 0, 0, 1),
    Field("led", 65, 1, True, 0, 0, 1),
    Field("status_return_level", 68, 1, True, 2, 0, 2),
    Field("registered_instruction", 69, 1, False, 0),
    Field("hardware_error_status", 70, 1, False, 0),
    Field("velocity_i_gain", 76, 2, True, 1920, 0, 16383),
    Field("velocity_p_gain", 78, 2, True, 100, 0, 16383),
    Field("position_d_gain", 80, 2, True, 0, 0, 16383),
    Field("position_i_gain", 82, 2, True, 0, 0, 16383),
    Field("position_p_gain", 84, 2, True, 800, 0, 16383),
    Field("feedforward_2nd_gain", 88, 2, True, 0, 0, 16383),
    Field("feedforward_1st_gain", 90, 2, True, 0, 0, 16383),
    # 20 ms per unit; 0 off; the servo sets −1 on expiry; the e-manual adds it in firmware v38
    Field("bus_watchdog", 98, 1, True, 0, 0, 127, True, since_firmware=38),
    Field("goal_pwm", 100, 2, True, 0, -885, 885, True),
    Field("goal_current", 102, 2, True, 0, -1193, 1193, True),
    Field("goal_velocity", 104, 4, True, 0, -1023, 1023, True),
    Field("profile_acceleration", 108, 4, True, 0, 0, 32767),
    Field("profile_velocity", 112, 4, True, 0, 0, 32767),
    Field("goal_position", 116, 4, True, 0, -1_048_575, 1_048_575, True),
    Field("realtime_tick", 120, 2, False, 0),
    Field("moving", 122, 1, False, 0),
    Field("moving_status", 123, 1, False, 0),
    Field("present_pwm", 124, 2, False, 0, signed=True),
    Field("present_current", 126, 2, False, 0, signed=True),
    Field("present_velocity", 128, 4, False, 0, signed=True),
    Field("present_position", 132, 4, False, 0, signed=True),
    Field("velocity_trajectory", 136, 4, False, 0, signed=True),
    Field("position_trajectory", 140, 4, False, 0, signed=True),
    Field("present_input_voltage", 144, 2, False, 120),
    Field("present_temperature", 146, 1, False, 30),
    Field("backup_ready", 147, 1, False, 0),
]


def _indirect(
    first_number: int, address_at: int, data_at: int, count: int
) -> tuple[list[Field], list[Field]]:
    """Indirect Address n (2 bytes, factory value: its own Indirect Data's address) and Indirect Data n."""
    addresses = [Field(f"indirect_address_{first_number + k}", address_at + 2 * k, 2, True, data_at + k,
                       RAM_AREA[0], RAM_AREA[1]) for k in range(count)]  # fmt: skip
    data = [Field(f"indirect_data_{first_number + k}", data_at + k, 1, True, 0, 0, 255) for k in range(count)]
    return addresses, data


INDIRECT_ADDRESSES, INDIRECT_DATA = (
    [*a, *b] for a, b in zip(_indirect(1, 168, 224, 28), _indirect(29, 578, 634, 28), strict=True)
)
FIELDS += INDIRECT_ADDRESSES + INDIRECT_DATA
INDIRECT_OF_DATA = {d.address: a for a, d in zip(INDIRECT_ADDRESSES, INDIRECT_DATA, strict=True)}
BY_NAME = {f.name: f for f in FIELDS}
BY_ADDRESS = {f.address: f for f in FIELDS}
OPERATING_MODES = {0, 1, 3, 4, 5, 16}
BAUD_RATES = {
    0: 9600,
    1: 57600,
    2: 115200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}

# Units (X-series e-manual): velocity 0.229 rev/min per LSB, acceleration 214.577 rev/min² per LSB,
# 4096 ticks per revolution.
TICKS_PER_REV = 4096
VELOCITY_UNIT_TICKS_PER_S = 0.229 / 60 * TICKS_PER_REV
ACCELERATION_UNIT_TICKS_PER_S2 = 214.577 / 3600 * TICKS_PER_REV
