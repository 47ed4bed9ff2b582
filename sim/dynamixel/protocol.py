"""Dynamixel Protocol 2.0 framing (ROBOTIS e-manual, "Protocol 2.0").

Packet: ``FF FF FD 00 | ID | LEN_L LEN_H | INST | params | CRC_L CRC_H``, LEN = len(params) + 3
(instruction) or + 4 (status: INST 0x55 and ERR). CRC-16, polynomial 0x8005, init 0, no reflection, over
header through last parameter. Byte stuffing: from INST to the last parameter, ``FF FF FD`` is sent as
``FF FF FD FD``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
STATUS = 0x55


class Instruction:
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class Error:
    """The status packet's error byte: a number in bits 0–6, bit 7 the hardware alert."""

    NONE = 0x00
    RESULT_FAIL = 0x01
    INSTRUCTION = 0x02
    CRC = 0x03
    DATA_RANGE = 0x04
    DATA_LENGTH = 0x05
    DATA_LIMIT = 0x06
    ACCESS = 0x07
    ALERT = 0x80


def _table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _table()


def crc16(data: bytes, crc: int = 0) -> int:
    """CRC-16/BUYPASS as Protocol 2.0 uses it; ``crc`` continues a previous value."""
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert 0xFD after every ``FF FF FD`` (body = instruction/status byte through last parameter)."""
    out = bytearray()
    for b in body:
        out.append(b)
        if len(out) >= 3 and out[-3:] == b"\xff\xff\xfd":
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the stuffing; an unstuffed ``FF FF FD xx`` (xx ≠ FD) is left as it is (dynamixel-sdk 4.1.0
    transmits unstuffed but self-consistent packets)."""
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if len(out) >= 3 and out[-3:] == b"\xff\xff\xfd" and i + 1 < len(body) and body[i + 1] == 0xFD:
            i += 1  # skip the stuffed 0xFD
        i += 1
    return bytes(out)


def frame(packet_id: int, body: bytes, *, stuffed: bool = True) -> bytes:
    """A whole packet from ``body`` (INST [ERR] params)."""
    if stuffed:
        body = stuff(body)
    head = HEADER + bytes([packet_id]) + (len(body) + 2).to_bytes(2, "little")
    crc = crc16(head + body)
    return head + body + crc.to_bytes(2, "little")


def status_packet(servo_id: int, error: int, params: bytes = b"") -> bytes:
    return frame(servo_id, bytes([STATUS, error]) + params)


def instruction_packet(packet_id: int, instruction: int, params: bytes = b"") -> bytes:
    return frame(packet_id, bytes([instruction]) + params)


@dataclass(frozen=True)
class Packet:
    """A received instruction packet (parameters unstuffed); ``crc_ok`` False for a corrupted one."""

    id: int
    instruction: int
    params: bytes
    crc_ok: bool


class PacketReader:
    """Incremental parser: feed bytes as they arrive, take whole packets out.

    Header search skips garbage and ignores a stuffed ``FF FF FD FD``; a packet whose length field is
    impossible is skipped byte by byte, as a device resynchronises on a noisy line.
    """

    MAX_LENGTH = 1024

    def __init__(self, inter_byte_timeout_s: float = 0.01):
        self._buf = bytearray()
        self.inter_byte_timeout_s = inter_byte_timeout_s
        self._last = -math.inf

    def feed(self, data: bytes, now: float | None = None) -> list[Packet]:
        """Whole packets from ``data``; ``now`` (monotonic seconds) drops a partial packet that waited
        longer than the inter-byte timeout for its next bytes."""
        if now is not None:
            if now - self._last > self.inter_byte_timeout_s:
                self._buf.clear()
            self._last = now
        self._buf.extend(data)
        packets = []
        while True:
            start = self._find_header()
            if start < 0:
                break
            del self._buf[:start]
            if len(self._buf) < 7:
                break
            length = int.from_bytes(self._buf[5:7], "little")
            if length < 3 or length > self.MAX_LENGTH:
                del self._buf[0]
                continue
            total = 7 + length
            if len(self._buf) < total:
                break
            raw = bytes(self._buf[:total])
            del self._buf[:total]
            crc_ok = crc16(raw[:-2]) == int.from_bytes(raw[-2:], "little")
            body = unstuff(raw[7:-2])
            packets.append(Packet(raw[4], body[0], body[1:], crc_ok))
        return packets

    def _find_header(self) -> int:
        i = 0
        while True:
            i = self._buf.find(HEADER[:3], i)
            if i < 0:
                # keep a possible partial header at the end
                keep = next((k for k in (2, 1) if self._buf.endswith(HEADER[:k])), 0)
                del self._buf[: len(self._buf) - keep]
                return -1
            if i + 3 < len(self._buf) and self._buf[i + 3] == 0xFD:  # stuffed data, not a header
                i += 1
                continue
            return i
