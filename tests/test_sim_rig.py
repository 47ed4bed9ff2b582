"""The simulated rig as drivers meet it: endpoints, real client libraries, a clean stop."""

import json
import os
import signal
import subprocess
import sys

from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler
from pymodbus.client import ModbusTcpClient

from sim.rig import SimRig
from sim.turntable import register_map as rm


def test_endpoints_answer_real_clients_and_stop_cleanly():
    with SimRig(speed_factor=10.0) as rig:
        e = rig.endpoints
        port = PortHandler(e.dynamixel)
        assert port.openPort()
        ph = PacketHandler(2.0)
        assert all(ph.ping(port, i)[1] == COMM_SUCCESS for i in e.servo_ids)
        port.closePort()
        host, tcp_port = e.modbus.split(":")
        client = ModbusTcpClient(host, port=int(tcp_port), timeout=1, retries=0)
        assert client.connect()
        assert not client.read_holding_registers(rm.STATUS, count=2, device_id=e.stage_unit).isError()
        assert not client.write_coil(e.lamp_coil, True, device_id=e.lamp_unit).isError()
        assert rig.turntable.stage.lamp
        client.close()
    # the autouse fixture fails this test if any thread is left running


def test_sim_serve_prints_endpoints_and_stops_on_sigint():
    env = dict(os.environ)
    proc = subprocess.Popen(
        [sys.executable, "-m", "hlr_lab.cli.main", "sim", "serve"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        endpoints = json.loads(proc.stdout.readline())
        assert set(endpoints) >= {"dynamixel", "modbus", "servo_ids"}
        port = PortHandler(endpoints["dynamixel"])
        assert port.openPort()
        assert PacketHandler(2.0).ping(port, endpoints["servo_ids"][0])[1] == COMM_SUCCESS
        port.closePort()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
