"""GVSP, the GigE Vision stream protocol: one frame (a "block") as the datagrams a device sends.

A block is a leader (payload type, timestamp, pixel format, size), data packets, and a trailer; each
datagram starts with status (2 bytes), block id (2; 1…65535, never 0), and the packet's format and id
(4: content type in bits 24–30, packet id in bits 0–23). Standard 16-bit block ids, big-endian fields
(GigE Vision 2.x §24). Each data packet carries the stream channel's packet size less the IP, UDP and
GVSP headers, the last one what is left — which is how a receiver counts the packets of a block.
"""

from __future__ import annotations

import struct

LEADER, TRAILER, PAYLOAD = 1, 2, 3
IMAGE, IMAGE_EXTENDED_CHUNK = 0x0001, 0x4001
HEADERS_BYTES = 20 + 8 + 8  # IP, UDP, GVSP: what a packet size counts besides its data
STATUS_RESENT = 0x0100  # a packet sent again on request (not an error: bit 15 clear)
_HEADER = struct.Struct(">HHI")
_IMAGE_LEADER = struct.Struct(">HHIIIIIIIHH")
_TRAILER = struct.Struct(">HHI")


def header(block_id: int, content: int, packet_id: int, status: int = 0) -> bytes:
    return _HEADER.pack(status, block_id, (content << 24) | packet_id)


def block(
    block_id: int,
    data: bytes,
    *,
    pixel_format: int,
    width: int,
    height: int,
    timestamp_ns: int,
    packet_bytes: int,
    chunks: bool,
) -> list[bytes]:
    """The datagrams of one block: leader, ``data`` cut to ``packet_bytes``-sized packets, trailer."""
    step = packet_bytes - HEADERS_BYTES
    payload_type = IMAGE_EXTENDED_CHUNK if chunks else IMAGE
    leader = header(block_id, LEADER, 0) + _IMAGE_LEADER.pack(
        0,
        payload_type,
        timestamp_ns >> 32,
        timestamp_ns & 0xFFFFFFFF,
        pixel_format,
        width,
        height,
        0,
        0,
        0,
        0,
    )
    view = memoryview(data)
    payload = [
        header(block_id, PAYLOAD, 1 + i) + view[at : at + step]
        for i, at in enumerate(range(0, len(data), step))
    ]
    trailer = header(block_id, TRAILER, 1 + len(payload)) + _TRAILER.pack(0, payload_type, height)
    return [leader, *payload, trailer]


def resent(packet: bytes) -> bytes:
    """``packet`` as sent again on request: the same, with the resent status."""
    return struct.pack(">H", STATUS_RESENT) + packet[2:]
