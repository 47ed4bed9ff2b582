"""``hlr-lab doctor``: is every device of the rig there and healthy? Plain words, and what to do."""

from __future__ import annotations

from pathlib import Path

import click
from rich.markup import escape
from rich.table import Table

from hlr_lab.cli.common import resolve_rig
from hlr_lab.cli.console import console
from hlr_lab.errors import RigNotReady
from hlr_lab.instrument.doctor import Finding, examine_rig

MARKS = {"ok": "[green]ok[/]", "warning": "[yellow]warning[/]", "problem": "[bold red]problem[/]"}


@click.command()
@click.option(
    "--rig", "rig_path", type=click.Path(dir_okay=False, path_type=Path), help="Rig file (rig.toml)."
)
@click.option("--sim", is_flag=True, help="Examine the built-in simulated rig (started for the purpose).")
def doctor(rig_path: Path | None, sim: bool) -> None:
    """Connect to every device of the rig and report identities, limits, temperatures and alarms.

    Nothing is configured, energised or moved. The exit status is 0 when no problem was found.

    \b
    Examples:
      hlr-lab doctor --rig rig.toml
      hlr-lab doctor --sim
    """
    rig = resolve_rig(rig_path, sim)
    with console.status(f"examining {rig.name}…"):
        if sim:
            # the simulator is reached only from the command line (the composition root)
            from sim.rig import SimRig
            from sim.targets import mirror_ball_scene
            from worlds.plan_world import world_geometry

            # any scene gives the world its camera (opening it takes no photograph)
            scene = mirror_ball_scene(0.02, (0.0, 0.0))
            with SimRig(scene=scene, **world_geometry(rig, runs=False)) as world:
                e = world.endpoints
                findings = examine_rig(
                    rig, gantry_port=e.dynamixel, stage_address=e.modbus, camera_endpoint=e.camera
                )
        else:
            findings = examine_rig(rig)
    console.print(_table(rig.name, findings))
    problems = sum(f.level == "problem" for f in findings)
    if problems:
        raise RigNotReady(f"{problems} problem(s) on {rig.source}; fix them and run hlr-lab doctor again")
    console.print("[green]the rig is ready[/]")


def _table(name: str, findings: list[Finding]) -> Table:
    table = Table(title=name, title_justify="left")
    for column in ("device", "state", "what it says / what to do"):
        table.add_column(column, overflow="fold")
    for f in findings:
        table.add_row(escape(f.device), MARKS[f.level], escape(f.message))
    return table
