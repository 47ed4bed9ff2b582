"""Benchmarks of the simulated devices, driven by the real client libraries (``hlr-lab bench sim``)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, PacketHandler, PortHandler
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from sim.dynamixel.bus import SimBus
from sim.turntable import register_map as rm
from sim.turntable.server import TurntableServer


def _timed(fn: Callable[[], int], n: int) -> dict[str, float]:
    times = []
    for _ in range(n):
        t = time.perf_counter()
        if fn() != COMM_SUCCESS:
            raise RuntimeError("a transaction failed during the benchmark")
        times.append(time.perf_counter() - t)
    times.sort()
    return {"median_ms": 1e3 * statistics.median(times), "p95_ms": 1e3 * times[int(0.95 * (n - 1))]}


def servo_round_trips(n: int = 1000) -> dict[str, dict[str, float]]:
    """Ping and a sync read of two servos' present positions, with dynamixel-sdk over the bus's pty
    (Return Delay Time 0, as a driver sets it)."""
    with SimBus.with_servos([1, 2]) as bus:
        for s in bus.servos:
            s.table[9] = 0
        port = PortHandler(bus.serve_pty())
        port.openPort()
        try:
            ph = PacketHandler(2.0)
            sync = GroupSyncRead(port, ph, 132, 4)
            sync.addParam(1)
            sync.addParam(2)
            return {
                "ping": _timed(lambda: ph.ping(port, 1)[1], n),
                "sync read, 2 servos": _timed(sync.txRxPacket, n),
                "fast sync read, 2 servos": _timed(sync.fastSyncRead, n),
            }
        finally:
            port.closePort()


def modbus_round_trips(n: int = 1000) -> dict[str, dict[str, float]]:
    """Reading the stage's status block (6 × int32) and writing a command, with pymodbus over TCP and RTU."""
    figures = {}
    with TurntableServer.simulated() as server:
        host, port = server.serve_tcp()
        clients = {
            "TCP": ModbusTcpClient(host, port=port, timeout=1, retries=0),
            "RTU 115200 Bd": ModbusSerialClient(server.serve_rtu(), baudrate=115_200, timeout=1, retries=0),
        }
        for name, client in clients.items():
            client.connect()
            try:
                figures[f"read status block, {name}"] = _timed(
                    lambda c=client: _ok(
                        c.read_holding_registers(rm.STATUS, count=12, device_id=rm.STAGE_UNIT)
                    ),
                    n,
                )
                figures[f"write command, {name}"] = _timed(
                    lambda c=client: _ok(c.write_registers(rm.COMMAND, [0, 0], device_id=rm.STAGE_UNIT)), n
                )
            finally:
                client.close()
    return figures


def _ok(response) -> int:
    return COMM_SUCCESS if not response.isError() else -1
