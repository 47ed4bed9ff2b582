"""Requests that pymodbus's server answers otherwise than the Modbus Application Protocol (v1.1b3) says,
answered here as the specification says a device must; given to the server as ``custom_pdu``.

* FC 1–4 with a quantity outside 1–2000 (bits) or 1–125 (registers): exception 3 (pymodbus cannot
  decode them, and answers ``80 01``).
* FC 5 with a value other than 0x0000 or 0xFF00: exception 3 (pymodbus switches the coil on).
* A function code the server does not implement: exception 1 under that code | 0x80 (pymodbus answers
  ``80 01``). Only on TCP, where the MBAP header says how long any request is; an RTU frame of an
  unknown function cannot be delimited, and stays unanswered, as on a real serial line.
* A request whose code is itself an exception code (≥ 0x80), and FC 8 with a sub-function pymodbus does
  not know: exception 1 (pymodbus fails on both inside its handler, logs a traceback and answers 4):
  :func:`received`, the server's ``trace_pdu``.
"""

from __future__ import annotations

import struct

from pymodbus.constants import ExcCodes
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.bit_message import ReadCoilsRequest, ReadDiscreteInputsRequest, WriteSingleCoilRequest
from pymodbus.pdu.decoders import DecodePDU
from pymodbus.pdu.register_message import ReadHoldingRegistersRequest, ReadInputRegistersRequest

COIL_ON, COIL_OFF = 0xFF00, 0x0000


def _counted(base: type[ModbusPDU], max_count: int) -> type[ModbusPDU]:
    """``base`` (a read request) whose quantity, 1 … ``max_count``, is checked when answered, not when
    decoded."""

    class Counted(base):
        def decode(self, data: bytes) -> None:
            self.address, self.count = struct.unpack(">HH", data[:4])

        async def datastore_update(self, context, device_id: int) -> ModbusPDU:
            if not 1 <= self.count <= max_count:
                return ExceptionResponse(self.function_code, ExcCodes.ILLEGAL_VALUE)
            return await super().datastore_update(context, device_id)

    Counted.__name__ = base.__name__
    return Counted


class CheckedCoilWrite(WriteSingleCoilRequest):
    """FC 5: only 0xFF00 (on) and 0x0000 (off) are values."""

    def decode(self, data: bytes) -> None:
        self.address, self.raw_value = struct.unpack(">HH", data[:4])
        self.bits = [self.raw_value == COIL_ON]

    async def datastore_update(self, context, device_id: int) -> ModbusPDU:
        if self.raw_value not in (COIL_ON, COIL_OFF):
            return ExceptionResponse(self.function_code, ExcCodes.ILLEGAL_VALUE)
        return await super().datastore_update(context, device_id)


def _unsupported(code: int) -> type[ModbusPDU]:
    class Unsupported(ModbusPDU):
        function_code = code

        def decode(self, data: bytes) -> None:
            self.data = data

        async def datastore_update(self, context, device_id: int) -> ModbusPDU:
            return ExceptionResponse(self.function_code, ExcCodes.ILLEGAL_FUNCTION)

    Unsupported.__name__ = f"Unsupported{code:02X}"
    return Unsupported


CHECKED = [_counted(c, c.MAX_COUNT) for c in (ReadCoilsRequest, ReadDiscreteInputsRequest, ReadHoldingRegistersRequest,
                                 ReadInputRegistersRequest)] + [CheckedCoilWrite]  # fmt: skip
UNSUPPORTED = [_unsupported(code) for code in range(1, 0x80) if code not in DecodePDU(True).pdu_table]


_DIAGNOSTICS = set(DecodePDU(True).pdu_sub_table.get(8, {}))  # the FC 8 sub-functions pymodbus answers


def received(sending: bool, pdu: ModbusPDU) -> ModbusPDU:
    """The server's ``trace_pdu``: a request it would fail on replaced by one answered with exception 1."""
    if sending:
        return pdu
    if isinstance(pdu, ExceptionResponse) or (
        pdu.function_code == 8 and pdu.sub_function_code not in _DIAGNOSTICS
    ):
        refused = _unsupported(pdu.function_code & 0x7F)()
        refused.dev_id, refused.transaction_id = pdu.dev_id, pdu.transaction_id
        return refused
    return pdu


def requests(*, tcp: bool) -> list[type[ModbusPDU]]:
    """The request classes a server on TCP (or RTU) is given."""
    return CHECKED + (UNSUPPORTED if tcp else [])
