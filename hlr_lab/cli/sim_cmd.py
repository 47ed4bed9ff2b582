"""``hlr-lab sim``: the simulated rig's devices as standalone endpoints."""

from __future__ import annotations

import json
import signal
import threading

import click

from hlr_lab.cli.common import console


@click.group()
def sim() -> None:
    """The simulated rig (servo bus on a pseudo-terminal, Modbus turntable and lamp relay on TCP)."""


@sim.command("serve")
@click.option(
    "--speed-factor",
    type=click.FloatRange(min=0.01),
    default=1.0,
    show_default=True,
    help="Simulated time runs this much faster than real time.",
)
def serve(speed_factor) -> int:
    """Run the simulated servo bus and turntable until interrupted; print their endpoints as one JSON line.

    Any Dynamixel or Modbus tool can talk to them.

    \b
    Example:
      hlr-lab sim serve
      {"dynamixel": "/dev/pts/7", "modbus": "127.0.0.1:40123", "servo_ids": [1, 2], ...}
    """
    from sim.rig import SimRig  # the simulator is reached only from the command line

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with SimRig(speed_factor=speed_factor) as rig:
        click.echo(json.dumps(rig.endpoints.as_dict()), nl=True)
        console.print("simulated rig running; Ctrl-C stops it")
        while not stop.wait(0.5):
            pass
    console.print("stopped")
    return 0
