"""The stage and lamp relay behind a real pymodbus server, on TCP (ephemeral port) or RTU over a pty.

The server runs its own asyncio loop in a thread. Every register access goes through an ``action``
that keeps the read-only registers current and turns writes into stage commands; faults can be
injected: unanswered requests, exception replies, a dropped connection.
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

from sim.turntable import register_map as rm
from sim.turntable.stage import RotaryStage


@dataclass
class ModbusFaults:
    no_reply: int = 0  # the next N requests go unanswered
    exception: int = 0  # the next N stage requests are answered with exception 4 (device failure)


def _int32(hi: int, lo: int) -> int:
    v = (hi << 16) | lo
    return v - (1 << 32) if v & 0x8000_0000 else v


def _words(v: int) -> tuple[int, int]:
    v &= 0xFFFF_FFFF
    return v >> 16, v & 0xFFFF


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
        stage = SimDevice(
            id=rm.STAGE_UNIT,
            simdata=[
                SimData(0, count=rm.STATUS, values=0, datatype=DataType.REGISTERS),
                SimData(
                    rm.STATUS,
                    count=rm.REGISTERS - rm.STATUS,
                    values=0,
                    datatype=DataType.REGISTERS,
                    readonly=True,
                ),
            ],
            action=self._stage_action,
        )
        relay = SimDevice(
            id=rm.RELAY_UNIT,
            simdata=[SimData(0, values=0, datatype=DataType.REGISTERS)],
            use_bit_addressing=True,
            action=self._relay_action,
        )
        return [stage, relay]

    async def _stage_action(self, function_code, start, address, count, registers, values):
        with self._lock:
            self.requests += 1
            if self.faults.exception > 0:
                self.faults.exception -= 1
                return ExcCodes.DEVICE_FAILURE
            if values is not None:
                error = self._write(address, values)
                if error:
                    return error
            self._refresh(registers, start)
        return None

    def _write(self, address: int, values: list[int]):
        s = self.stage
        fields = [
            a
            for a in range(address - address % 2, address + len(values), 2)
            if address <= a and a + 1 < address + len(values)
        ]
        decoded = {a: _int32(values[a - address], values[a + 1 - address]) for a in fields}
        if any(not s.valid(a, v) for a, v in decoded.items()):
            return ExcCodes.ILLEGAL_VALUE
        for a, v in decoded.items():
            if a in s.data:
                s.data[a] = v
            elif a == rm.TRIGGER and v == 1:
                s.start()
                values[a - address : a - address + 2] = [0, 0]  # the trigger reads back 0
            elif a == rm.COMMAND:
                s.set_command(v)
        return None

    def _refresh(self, registers: list[int], start: int) -> None:
        s = self.stage
        for address, value in (
            (rm.STATUS, s.status()),
            (rm.ALARM_CODE, s.alarm),
            (rm.POSITION, round(s.position())),
            (rm.VELOCITY, round(s.velocity())),
            (rm.LIMIT_LOW, s.limits[0]),
            (rm.LIMIT_HIGH, s.limits[1]),
            (rm.COMMAND, s.command),
        ):
            registers[address - start : address - start + 2] = _words(value)

    async def _relay_action(self, function_code, start, address, count, registers, values):
        with self._lock:
            self.requests += 1
            if values is not None and address == rm.LAMP_COIL:
                self.stage.lamp = bool(values[0])
        return None

    def _trace(self, sending: bool, packet: bytes) -> bytes:
        if sending and self.faults.no_reply > 0:
            self.faults.no_reply -= 1
            return b""
        return packet

    # -- transports -----------------------------------------------------------------------------
    def serve_tcp(self, host: str = "127.0.0.1") -> tuple[str, int]:
        server = self._run(
            self._start(ModbusTcpServer, self._devices(), address=(host, 0), trace_packet=self._trace)
        )
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
                trace_packet=self._trace,
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
