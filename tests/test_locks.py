"""Locks on sessions and device links: held by a process for its life, freed by its death however it
dies, and a refusal that names the holder."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from hlr_lab.instrument.locks import Busy, hold_devices, hold_session, link_key

HOLDER = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from hlr_lab.instrument.locks import hold_devices, hold_session
    with hold_session(Path(sys.argv[1])), hold_devices([("the gantry's servo bus", sys.argv[2])]):
        print("holding", flush=True)
        time.sleep(60)
    """
)


def test_a_lock_names_its_holder_and_dies_with_it(tmp_path):
    session, port = tmp_path / "session", str(tmp_path / "ttyUSB0")
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(session), port], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "holding"
        with pytest.raises(Busy, match=rf"session {session} is in use by PID {holder.pid} \(.*-c .*, since "):
            hold_session(session).__enter__()
        with pytest.raises(Busy, match=rf"the gantry's servo bus \({port}\) is in use by PID {holder.pid}"):
            hold_devices([("the gantry's servo bus", port)]).__enter__()
        os.kill(holder.pid, signal.SIGKILL)  # no handler runs: the kernel frees the locks
        holder.wait()
        with hold_session(session), hold_devices([("the gantry's servo bus", port)]):
            pass
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait()
        holder.stdout.close()


def test_one_port_by_any_name_is_one_lock(tmp_path):
    device = tmp_path / "ttyUSB0"
    device.touch()
    alias = tmp_path / "usb-FTDI_FT232R-if00-port0"
    alias.symlink_to(device)
    assert link_key(str(alias)) == link_key(str(device))
    assert link_key("127.0.0.1:502") != link_key("127.0.0.1:503")
    # two devices on one link (the lamp relay on the turntable's Modbus link) share its lock
    with (
        hold_devices([("the turntable", "127.0.0.1:502"), ("the lamp relay", "127.0.0.1:502")]),
        pytest.raises(Busy),
    ):
        hold_devices([("the turntable", "127.0.0.1:502")]).__enter__()
