"""GVCP, the GigE Vision control protocol: the numbers and the packet layouts a device answers with.

Every field is big-endian. A command is an 8-byte header — key 0x42, flags (bit 0: acknowledge
required), command, payload length, request id — and its payload; an acknowledge is status, answer
code (the command's + 1), payload length, the request's id, and its payload (GigE Vision 2.x §15).
Pure functions: the socket and the state live in :mod:`sim.gige.device`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

PORT = 3956  # GVCP's one UDP port: each simulated camera takes its own loopback address

KEY = 0x42
FLAG_ACK_REQUIRED = 0x01
DISCOVERY, PACKETRESEND, READREG, WRITEREG, READMEM, WRITEMEM = 0x0002, 0x0040, 0x0080, 0x0082, 0x0084, 0x0086
MAX_MEM_BYTES = 536  # the largest READMEM/WRITEMEM payload a 576-byte datagram carries

# status codes (GEV_STATUS_*)
SUCCESS = 0x0000
NOT_IMPLEMENTED = 0x8001
INVALID_PARAMETER = 0x8002
INVALID_ADDRESS = 0x8003
WRITE_PROTECT = 0x8004
BAD_ALIGNMENT = 0x8005
ACCESS_DENIED = 0x8006
INVALID_HEADER = 0x800E

# bootstrap registers (GigE Vision §28): what every device has at these addresses
VERSION = 0x0000
DEVICE_MODE = 0x0004
MAC_HIGH, MAC_LOW = 0x0008, 0x000C
IP_CONFIG_SUPPORTED, IP_CONFIG_CURRENT = 0x0010, 0x0014
CURRENT_IP, CURRENT_MASK, CURRENT_GATEWAY = 0x0024, 0x0034, 0x0044
MANUFACTURER_NAME, MODEL_NAME, DEVICE_VERSION = 0x0048, 0x0068, 0x0088
MANUFACTURER_INFO, SERIAL_NUMBER, USER_NAME = 0x00A8, 0x00D8, 0x00E8
DISCOVERY_DATA_BYTES = 0x00F8
FIRST_URL, SECOND_URL, URL_BYTES = 0x0200, 0x0400, 512
N_INTERFACES = 0x0600
N_MESSAGE_CHANNELS, N_STREAM_CHANNELS = 0x0900, 0x0904
GVCP_CAPABILITY = 0x0934
HEARTBEAT_TIMEOUT = 0x0938
TICK_FREQUENCY_HIGH, TICK_FREQUENCY_LOW = 0x093C, 0x0940
TIMESTAMP_CONTROL, TIMESTAMP_HIGH, TIMESTAMP_LOW = 0x0944, 0x0948, 0x094C
CONTROL_PRIVILEGE = 0x0A00
SC_PORT, SC_PACKET_SIZE, SC_PACKET_DELAY, SC_DESTINATION = 0x0D00, 0x0D04, 0x0D08, 0x0D18

CCP_EXCLUSIVE, CCP_CONTROL = 0x1, 0x2
SCPS_FIRE_TEST, SCPS_DO_NOT_FRAGMENT, SCPS_SIZE = 1 << 31, 1 << 30, 0xFFFF
CAPABILITY_WRITE_MEMORY, CAPABILITY_PACKET_RESEND = 1 << 1, 1 << 2  # bit numbers from the least significant
CAPABILITY_SERIAL_NUMBER, CAPABILITY_USER_NAME = 1 << 30, 1 << 31

HEADER = struct.Struct(">BBHHH")


@dataclass(frozen=True)
class Command:
    """One GVCP command as received: its code, request id, whether it wants an acknowledge, payload."""

    code: int
    request_id: int
    ack_required: bool
    payload: bytes


def parse_command(datagram: bytes) -> Command | None:
    """The command in ``datagram``, or None for anything that is not one (wrong key, cut short): a device
    ignores such datagrams rather than answering what it cannot attribute."""
    if len(datagram) < HEADER.size:
        return None
    key, flags, code, length, request_id = HEADER.unpack_from(datagram)
    payload = datagram[HEADER.size : HEADER.size + length]
    if key != KEY or len(payload) != length:
        return None
    return Command(code, request_id, bool(flags & FLAG_ACK_REQUIRED), payload)


def ack(command: Command, payload: bytes = b"", status: int = SUCCESS) -> bytes:
    """The acknowledge of ``command``: ``status``, the answer code (command + 1), ``payload``."""
    return (
        HEADER.pack(status >> 8, status & 0xFF, command.code + 1, len(payload), command.request_id) + payload
    )


def words(payload: bytes) -> list[int]:
    """A payload of big-endian 32-bit words (register addresses, address/value pairs)."""
    return list(struct.unpack(f">{len(payload) // 4}I", payload[: len(payload) // 4 * 4]))
