"""The simulated stage's Modbus map: an Oriental Motor AZ series driver's (AZ Series Function Edition,
HM-60262E, "Modbus RTU control": direct data operation, driver input command, driver output status,
present alarm, monitor commands, maintenance commands). Addresses are register numbers (0-based, as on
the wire); 32-bit values span two registers, the upper word first, as the AZ keeps them (Oriental Motor
FAQ No. 331, https://www.orientalmotor.eu/eu/support/faq/0331: operation data No. 0 at 1800h, a position
at +2 upper and +3 lower, two's complement). The addresses and bits below agree with three independent
AZ client libraries, one of them written after Oriental Motor's own sample programs (direct data at
0058h, the command's lower word at 007Dh, status 007Eh, alarm 0080h, feedback position 00CCh, feedback
speed 00D0h in Hz, alarm reset 0180h); the manual's page numbers could not be checked where this was
written: see docs/rig.example.toml for overriding any address on a bench that differs.

Unit 1, the stage — holding registers (address: name, access, meaning):

* 0058h (88): data_no, RW — operation data No. of the direct data operation, 0–255
* 005Ah (90): op_type, RW — 1 absolute, 2 incremental (command position), 3 incremental (feedback)
* 005Ch (92): target, RW — position (absolute) or travel (incremental), steps
* 005Eh (94): speed, RW — operating speed, Hz (steps/s), 1 … max_speed
* 0060h (96): acceleration, RW — starting/changing rate, 0.001 kHz/s (= steps/s²), > 0
* 0062h (98): deceleration, RW — stopping rate, same unit, > 0
* 0064h (100): current, RW — operating current, 0.1 % of the rated current, 0 … 1000
* 0066h (102): trigger, RW — 1: start with all the data above; 0: none; −1 … −7: start when that
  item is next written (−1 current, −2 deceleration, −3 acceleration, −4 speed, −5 position,
  −6 operation type, −7 data No.); a 1 reads 0 once it has acted
* 0068h (104): forwarding, RW — forwarding destination: 0 execution memory, 1 buffer memory
* 007Ch (124): command, RW — driver input command (reference), lower word, acted on as bits rise:
  START 0x08, ZHOME 0x10, STOP 0x20, FREE 0x40 (held: de-energised), ALM-RST 0x80 (NET-IN3–7 as
  shipped)
* 007Eh (126): status, R — driver output status, lower word: HOME-END 0x10, READY 0x20, ALM-A 0x80,
  SYS-BSY 0x100, MOVE 0x2000, IN-POS 0x4000 (NET-OUT4, 5, 7, 8, 13, 14 as shipped)
* 0080h (128): alarm_code, R — present alarm: 0 none, 67h software overtravel, 30h overload, 41h
  (EEPROM error) for an injected device fault
* 00CCh (204): position, R — feedback position, steps
* 00D0h (208): velocity, R — feedback speed, Hz
* 0180h–018Dh (384–397): maintenance commands, RW — each executed when written 1 after 0: 0180h alarm
  reset, 018Ah P-PRESET (the position becomes the preset position, 0, while the axis stands; HOME-END
  comes on); the others (alarm and error histories, 018Ch configuration) are accepted with nothing
  simulated to act on; values other than 0 and 1 are exception 3

A write with a bad value (op_type not 1–3, speed ≤ 0 or too high, acceleration ≤ 0, current > 1000,
trigger outside −7…1) is exception 3, also when a 32-bit field is written one half at a time (FC 6:
the other half as it stands); an address outside these is exception 2. The data registers read what
the drive will use (its defaults until written); a read or write may take one half of a 32-bit field
(the lower word of the driver input command at 007Dh, say, as Oriental Motor's own examples write it).
The stage answers FC 3, 6, 16 and 23; other functions are exception 1 (sim.turntable.server). Software
overtravel limits are the drive's parameters (not on this map): a move beyond them raises alarm 67h.

Unit 2, the lamp relay — coil 0: the lamp (on = True); FC 1, 5 (0xFF00 or 0x0000 only) and 15.
Any other unit: exception 0Bh (gateway target failed to respond).
"""

STAGE_UNIT = 1
RELAY_UNIT = 2
LAMP_COIL = 0

DATA_NO, OP_TYPE, TARGET, SPEED, ACCELERATION, DECELERATION, CURRENT, TRIGGER, FORWARDING = range(
    0x58, 0x6A, 2
)
COMMAND = 0x7C
STATUS, ALARM_CODE = 0x7E, 0x80
POSITION, VELOCITY = 0xCC, 0xD0
MAINTENANCE_ALARM_RESET, MAINTENANCE_P_PRESET, MAINTENANCE_END = 0x180, 0x18A, 0x18E
MAINTENANCE = range(MAINTENANCE_ALARM_RESET, MAINTENANCE_END, 2)
BLOCKS = ((DATA_NO, FORWARDING + 2, True), (COMMAND, COMMAND + 2, True), (STATUS, ALARM_CODE + 2, False),
          (POSITION, VELOCITY + 2, False),
          (MAINTENANCE_ALARM_RESET, MAINTENANCE_END, True))  # fmt: skip  # (first, end, writable) of each run

START, ZHOME, STOP, FREE, ALARM_RESET = 0x08, 0x10, 0x20, 0x40, 0x80
HOME_END, READY, ALARM, BUSY, MOVE, IN_POS = 0x10, 0x20, 0x80, 0x100, 0x2000, 0x4000
ALARM_OVERTRAVEL, ALARM_OVERLOAD, ALARM_DEVICE = 0x67, 0x30, 0x41
ABSOLUTE, INCREMENTAL, INCREMENTAL_FEEDBACK = 1, 2, 3
TRIGGER_ALL = 1
TRIGGERED_BY = {
    -1: CURRENT,
    -2: DECELERATION,
    -3: ACCELERATION,
    -4: SPEED,
    -5: TARGET,
    -6: OP_TYPE,
    -7: DATA_NO,
}
