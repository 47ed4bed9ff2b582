"""``hlr-lab sim``: the simulated rig's devices as standalone endpoints."""

from __future__ import annotations

import json
import signal
import threading

import click

from hlr_lab.cli.common import object_offset_option, speed_factor_option, true_rig_option
from hlr_lab.cli.console import console


@click.group()
def sim() -> None:
    """The simulated rig (servo bus on a pseudo-terminal, Modbus turntable and lamp relay, camera)."""


@sim.command("serve")
@click.option(
    "--scene",
    "scene_spec",
    metavar="FILE|builtin:NAME",
    help="Also serve a camera photographing this scene: a scene file (format: docs/formats.md, Scene files), "
    "builtin:cylinder (the paper's 4.2) or builtin:lumpy (four materials).",
)
@true_rig_option
@object_offset_option
@speed_factor_option("Simulated")
def serve(scene_spec, true_rig, object_offset, speed_factor) -> int:
    """Run the simulated devices until interrupted; print their endpoints as one JSON line.

    Any Dynamixel or Modbus tool can talk to the servo bus and the turntable. With --scene, a GigE Vision
    camera on its own loopback address ("camera": "127.0.0.N") renders the scene where the simulated axes
    are; any GenICam client opens it (arv-tool-0.8 -a 127.0.0.N features; docs/camera.md).

    \b
    Examples:
      hlr-lab sim serve
      {"dynamixel": "/dev/pts/7", "modbus": "127.0.0.1:40123", "servo_ids": [1, 2], ...}
      hlr-lab sim serve --scene builtin:cylinder
      hlr-lab sim serve --scene builtin:lumpy --true-rig builtin:bench-offsets
    """
    from worlds.plan_world import ObjectOffset  # the simulator: CLI only (the composition root)
    from worlds.standalone import served_world

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with console.status("starting the simulated rig…"):
        offset = None if object_offset is None else ObjectOffset.from_option(object_offset)
        rig = served_world(scene_spec, true_rig, speed_factor, offset)
    with rig:
        click.echo(json.dumps(rig.endpoints.as_dict()), nl=True)
        console.print("simulated rig running; Ctrl-C stops it")
        while not stop.wait(0.5):
            pass
    console.print("stopped")
    return 0
