"""The stage and lamp relay behind a real pymodbus server, on TCP (ephemeral port) or RTU over a pty.

The server runs its own asyncio loop in a thread. Every register access goes through an ``action``
that keeps the registers current (status and position, and the operation data the drive will use) and
turns writes into stage commands; faults can be injected: unanswered requests, exception replies, a
dropped connection.

As the Modbus Application Protocol says a device answers (beyond what pymodbus does by itself:
:mod:`sim.turntable.conformance`):
* a function the device does not have is exception 1 (the stage: FC 3, 6, 16 and 23 on its holding
  registers, no input registers or coils; the relay: FC 1, 5 and 15 on its coils);
* a 32-bit field written one half at a time (FC 6) is checked whole, with its other half as it stands:
  a speed of 0 is exception 3 however it is written;
* a unit that is not there is exception 0x0B (gateway target failed to respond) on TCP, whose endpoint
  plays the gateway in front of an RS-485 line, as a real AZ driver (Modbus RTU only) is reached over
  TCP; on RTU it is silence, as on a real line, where only the addressed device answers (an independent
  RTU client, minimalmodbus, hears nothing and times out);
* the relay's coil reads the lamp as it is, whichever transport last switched it.
"""

from __future__ import annotations

import asyncio
import os
import select
import threading
import time
import tty
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from sim.turntable import conformance
from sim.turntable import register_map as rm
from sim.turntable.stage import RotaryStage


@dataclass
class ModbusFaults:
    no_reply: int = 0  # the next N requests go unanswered
    exception: int = 0  # the next N stage requests are answered with exception 4 (device failure)


STAGE_FUNCTIONS = {3, 6, 16, 23}  # holding registers only (the AZ driver's list of function codes)
RELAY_FUNCTIONS = {1, 5, 15}  # coils
READS = {3, 23}


def _int32(hi: int, lo: int) -> int:
    v = (hi << 16) | lo
    return v - (1 << 32) if v & 0x8000_0000 else v


def _words(v: int) -> tuple[int, int]:
    v &= 0xFFFF_FFFF
    return v >> 16, v & 0xFFFF


def _show(registers: list[int], start: int, address: int, value: int) -> None:
    """Put the 32-bit ``value`` of the field at ``address`` into ``registers`` (a request's window from
    ``start``), each of its words that the window holds: a request may take one half of a field."""
    for a, word in zip((address, address + 1), _words(value), strict=True):
        if 0 <= a - start < len(registers):
            registers[a - start] = word


class TurntableServer:
    def __init__(self, stage: RotaryStage):
        self.stage = stage
        self.faults = ModbusFaults()
        self.requests = 0  # Modbus requests served, stage and relay (for the acquisition benchmark)
        self._lock = threading.Lock()
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="sim-modbus", daemon=True)
        self._thread.start()
        self._servers: list = []
        self._fds: list[int] = []
        self._bridge: threading.Thread | None = None
        self._stop = threading.Event()

    @classmethod
    def simulated(cls, *, speed_factor: float = 1.0, **stage_kw) -> TurntableServer:
        t0 = time.monotonic()
        return cls(RotaryStage(lambda: (time.monotonic() - t0) * speed_factor, **stage_kw))

    # -- devices ------------------------------------------------------------------------------
    def _devices(self) -> list[SimDevice]:
        # pymodbus hands a request for a unit it does not have to unit 0: that one says "no such unit"
        absent = SimDevice(
            id=0,
            simdata=[SimData(0, count=65536, values=0, datatype=DataType.REGISTERS)],
            action=self._absent_action,
        )
        stage = SimDevice(
            id=rm.STAGE_UNIT,
            simdata=[
                SimData(
                    first, count=end - first, values=0, datatype=DataType.REGISTERS, readonly=not writable
                )
                for first, end, writable in rm.BLOCKS
            ],
            action=self._stage_action,
        )
        relay = SimDevice(
            id=rm.RELAY_UNIT,
            simdata=[SimData(0, values=0, datatype=DataType.REGISTERS)],
            use_bit_addressing=True,
            action=self._relay_action,
        )
        return [absent, stage, relay]

    async def _absent_action(self, function_code, start, address, count, registers, values):
        return ExcCodes.GATEWAY_NO_RESPONSE

    async def _stage_action(self, function_code, start, address, count, registers, values):
        with self._lock:
            self.requests += 1
            if function_code not in STAGE_FUNCTIONS:
                return ExcCodes.ILLEGAL_FUNCTION
            if self.faults.exception > 0:
                self.faults.exception -= 1
                return ExcCodes.DEVICE_FAILURE
            if values is not None:
                error = self._write(address, values, registers, start)
                if error:
                    return error
            self._refresh(registers, start)
            if function_code in READS:
                # a trigger of 1 acts once: echoed as written, then read as 0 (a negative one stays)
                _show(registers, start, rm.TRIGGER, self.stage.trigger)
        return None

    def _write(self, address: int, values: list[int], registers: list[int], start: int):
        """Act on a write of ``values`` at ``address``; each 32-bit field it touches is taken whole, its
        other half as the registers hold it (``registers`` from ``start``), and checked before any is
        applied."""
        s = self.stage
        words = {a: registers[a - start] for a in range(address - address % 2, address + len(values) + 1)
                 if 0 <= a - start < len(registers)}  # fmt: skip
        words.update({address + i: v for i, v in enumerate(values)})
        fields = range(address - address % 2, address + len(values), 2)
        decoded = {a: _int32(words.get(a, 0), words.get(a + 1, 0)) for a in fields}
        if any(not s.valid(a, v) for a, v in decoded.items()):
            return ExcCodes.ILLEGAL_VALUE
        started = False
        for a, v in decoded.items():
            if a in s.data:
                s.data[a] = v
            elif a == rm.TRIGGER:
                s.trigger = v if v < 0 else 0
                started |= v == rm.TRIGGER_ALL
            elif a == rm.COMMAND:
                s.set_command(v)
            elif a in rm.MAINTENANCE:
                s.maintain(a, v)
        # a negative trigger: the named item's write starts the move with the data as it now stands
        started |= s.trigger < 0 and rm.TRIGGERED_BY[s.trigger] in decoded
        if started:
            s.start()
        return None

    def _refresh(self, registers: list[int], start: int) -> None:
        s = self.stage
        for address, value in (
            *s.data.items(),  # what the drive will use, as a fresh drive shows its defaults
            (rm.STATUS, s.status()),
            (rm.ALARM_CODE, s.alarm),
            (rm.POSITION, round(s.position())),
            (rm.VELOCITY, round(s.velocity())),
            (rm.COMMAND, s.command),
            *s.maintenance.items(),
        ):
            _show(registers, start, address, value)

    async def _relay_action(self, function_code, start, address, count, registers, values):
        with self._lock:
            self.requests += 1
            if function_code not in RELAY_FUNCTIONS:
                return ExcCodes.ILLEGAL_FUNCTION
            if values is not None and address == rm.LAMP_COIL:
                self.stage.lamp = bool(values[0])
            elif values is None:  # a read shows the lamp as it is (each transport has its own store)
                word, bit = divmod(rm.LAMP_COIL, 16)  # coils 16 to a register, coil 0 its lowest bit
                registers[word] = registers[word] & ~(1 << bit) | (int(self.stage.lamp) << bit)
        return None

    def _trace(self, sending: bool, packet: bytes) -> bytes:
        if sending and self.faults.no_reply > 0:
            self.faults.no_reply -= 1
            return b""
        return packet

    def _trace_rtu(self, sending: bool, packet: bytes) -> bytes:
        """As :meth:`_trace`; and a reply on behalf of a unit not on the line (an RTU frame begins with
        its unit's address) is not sent: a serial line has no gateway to answer for it."""
        if sending and packet[:1] not in (bytes([rm.STAGE_UNIT]), bytes([rm.RELAY_UNIT])):
            return b""
        return self._trace(sending, packet)

    # -- transports -----------------------------------------------------------------------------
    def serve_tcp(self, host: str = "127.0.0.1") -> tuple[str, int]:
        server = self._run(
            self._start(ModbusTcpServer, self._devices(), address=(host, 0), trace_packet=self._trace,
                        trace_pdu=conformance.received, custom_pdu=conformance.requests(tcp=True))
        )  # fmt: skip
        return host, server.transport.sockets[0].getsockname()[1]

    def serve_rtu(self, baudrate: int = 115_200) -> str:
        """RTU on a pty pair bridged to the server's own pty; returns the device path a client opens."""
        server_master, server_slave = os.openpty()
        client_master, client_slave = os.openpty()
        for fd in (server_slave, client_slave):
            tty.setraw(fd)
        self._fds += [server_master, server_slave, client_master, client_slave]
        self._run(
            self._start(
                ModbusSerialServer,
                self._devices(),
                port=os.ttyname(server_slave),
                baudrate=baudrate,
                trace_packet=self._trace_rtu,
                trace_pdu=conformance.received,
                custom_pdu=conformance.requests(tcp=False),
            )
        )
        self._bridge = threading.Thread(
            target=self._pump, args=(server_master, client_master), daemon=True, name="sim-modbus-rtu-bridge"
        )
        self._bridge.start()
        return os.ttyname(client_slave)

    async def _start(self, kind, *args, **kwargs):
        server = kind(*args, **kwargs)  # pymodbus servers must be made inside their event loop
        await server.serve_forever(background=True)
        self._servers.append(server)
        return server

    def _pump(self, a: int, b: int) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([a, b], [], [], 0.05)
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    return
                os.write(b if fd == a else a, data)

    def disconnect_clients(self) -> None:
        """An injected fault: drop every open connection (the client sees the link go)."""

        def close_all():
            for server in self._servers:
                for conn in list(getattr(server, "active_connections", {}).values()):
                    conn.close()

        self._loop.call_soon_threadsafe(close_all)

    def _run(self, coro):
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout=10)

    def close(self) -> None:
        self._stop.set()
        for server in self._servers:
            self._run(server.shutdown())
        self._servers = []
        if self._bridge:
            self._bridge.join(timeout=2)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5)
        self._loop.close()
        for fd in self._fds:
            os.close(fd)
        self._fds = []

    def __enter__(self) -> TurntableServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
