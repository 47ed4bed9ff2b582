"""The simulated stage's Modbus map, in the style of Oriental Motor's AZ "direct data operation".

Unit 1, the stage — holding registers, 32-bit values over two registers, high word first:

| address | name          | access | meaning |
|--------:|---------------|--------|---------|
|       0 | op_type       | RW     | 1 absolute positioning, 2 incremental |
|       2 | target_steps  | RW     | position (absolute) or distance (incremental), steps |
|       4 | speed         | RW     | steps/s, 1 … max_speed |
|       6 | acceleration  | RW     | steps/s², > 0 |
|       8 | deceleration  | RW     | steps/s², > 0 |
|      10 | current       | RW     | per mille of rated current, 0 … 1000 |
|      12 | trigger       | RW     | write 1: start the operation above (reads back 0) |
|      20 | command       | RW     | input bits, acted on as they rise: START 0x08, ZHOME 0x10, |
|         |               |        | STOP 0x20, FREE 0x40 (held: de-energised), ALM-RST 0x80 |
|      30 | status        | R      | output bits: READY 0x01, MOVE 0x02, IN-POS 0x04, HOME-END 0x08, ALM 0x80 |
|      32 | alarm_code    | R      | 0 none, 0x66 software overtravel, 0x30 overload, 0x41 injected device fault |
|      34 | position      | R      | present (encoder) position, steps |
|      36 | velocity      | R      | present speed, steps/s |
|      38 | limit_low     | R      | software overtravel limits, steps |
|      40 | limit_high    | R      |  |

Writing a bad value (op_type not 1/2, speed ≤ 0 or too high, acceleration ≤ 0, current > 1000) is
answered with exception 3 (illegal value), also when it is written one half at a time (FC 6: the other
half as it stands); an address outside the map with exception 2. The data registers read what the
drive will use (its defaults until written). The stage answers FC 3, 6, 16 and 23; other functions are
exception 1 (sim.turntable.server).
Unit 2, the lamp relay — coil 0: the lamp (on = True); FC 1, 5 (0xFF00 or 0x0000 only) and 15.
Any other unit: exception 0x0B (gateway target failed to respond).

This is not yet a real AZ driver's map (Oriental Motor documents the AZ series on Modbus RTU with
direct data operation from 0058h, driver input command at 007Ch, output status at 007Eh, present alarm
at 0080h); a rig file's ``[turntable] registers = {…}`` moves the driver's addresses (docs/rig.example.toml).
"""

STAGE_UNIT = 1
RELAY_UNIT = 2
LAMP_COIL = 0

OP_TYPE, TARGET, SPEED, ACCELERATION, DECELERATION, CURRENT, TRIGGER = 0, 2, 4, 6, 8, 10, 12
COMMAND = 20
STATUS, ALARM_CODE, POSITION, VELOCITY, LIMIT_LOW, LIMIT_HIGH = 30, 32, 34, 36, 38, 40
REGISTERS = 42  # holding registers 0 … 41

START, ZHOME, STOP, FREE, ALARM_RESET = 0x08, 0x10, 0x20, 0x40, 0x80
READY, MOVE, IN_POS, HOME_END, ALARM = 0x01, 0x02, 0x04, 0x08, 0x80
ALARM_OVERTRAVEL, ALARM_OVERLOAD, ALARM_DEVICE = 0x66, 0x30, 0x41
ABSOLUTE, INCREMENTAL = 1, 2
