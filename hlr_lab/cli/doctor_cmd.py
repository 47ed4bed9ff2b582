"""``hlr-lab doctor``: is every device of the rig there and healthy? Plain words, and what to do."""

from __future__ import annotations

from pathlib import Path

import click

from hlr_lab.cli.common import FILE, resolve_rig
from hlr_lab.cli.console import console
from hlr_lab.display.doctor import findings_table
from hlr_lab.errors import RigNotReady
from hlr_lab.instrument.doctor import examine_rig


@click.command()
@click.option("--rig", "rig_path", type=FILE, help="Rig file (rig.toml).")
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
            from worlds.standalone import examine_simulated  # the simulator: CLI only (the composition root)

            findings = examine_simulated(rig)
        else:
            findings = examine_rig(rig)
    console.print(findings_table(rig.name, findings))
    problems = sum(f.level == "problem" for f in findings)
    if problems:
        raise RigNotReady(f"{problems} problem(s) on {rig.source}; fix them and run hlr-lab doctor again")
    console.print("[green]the rig is ready[/]")
