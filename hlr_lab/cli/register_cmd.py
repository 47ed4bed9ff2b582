"""``hlr-lab register``: measure where the object lies on the plate and plan again for it. The work is
:func:`hlr_lab.registration.register_plan`'s; this module parses options, starts the simulated world when
asked, and prints."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import click
from rich.markup import escape

from hlr_lab.cli.common import (
    FILE,
    FOLDER,
    believed_rig,
    object_offset_option,
    rig_options,
    speed_factor_option,
)
from hlr_lab.cli.console import console
from hlr_lab.cli.plan_cmd import EXIT_UNCOVERED
from hlr_lab.display.acquire import pose_progress
from hlr_lab.display.registration import registration_lines
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import read_plan
from hlr_lab.instrument.devices import Links
from hlr_lab.placement.photographs import registration_lamps
from hlr_lab.registration import Registered, register_plan
from hlr_lab.registration.capture import VIEWS


def default_folder(output: Path) -> Path:
    """Where the photographs go without ``--out``: beside the placed plan, named after it and the time."""
    return output.with_name(f"{output.stem}-photographs-{time.strftime('%Y%m%d-%H%M%S')}")


@click.command("register")
@click.option("--plan", "plan_path", type=FILE, required=True, help="plan.json of the object on the plate.")
@rig_options("Register on the simulated rig (its object where --scene's placed or --object-offset puts it).")
@click.option(
    "--scene",
    "scene_path",
    type=FILE,
    help="With --sim: the simulated world (sim scene file; its mesh must be the plan's).",
)
@object_offset_option
@click.option("-o", "--output", type=FILE, required=True, help="The placed plan to write (placed.json).")
@click.option(
    "--out",
    type=FOLDER,
    help="Folder for the photographs (new, or a stopped registration's: it resumes). Default: beside -o, "
    "named after it and the time.",
)
@click.option(
    "--from",
    "from_dir",
    type=click.Path(file_okay=False, exists=True, path_type=Path),
    help="Solve again from the photographs of an earlier registration (no rig needed).",
)
@speed_factor_option("With --sim: simulated")
def register(
    plan_path, rig_path, sim, true_rig, scene_path, object_offset, output, out, from_dir, speed_factor
):
    """Photograph the object where it lies, measure its placement, and plan again for it.

    The turntable turns the object through six angles; at each, the gantry lamp lights it from four
    places (two beside it, one above the camera, one high) through the rig's exposure bracket. The
    object's outline in each photograph gives where it lies: any turn about the axis, up to 3 cm off it,
    tilts up to 5°; a shape whose outline does not fix its turn (a cylinder) is turned by its colour
    regions. -o is the plan made again for the measured placement (same regions and settings), with an
    object.placement record: the offset from where the plan assumed the object, the standard errors,
    the outline's residual. The photographs and summary.html (each view with the registered outline
    and region borders drawn over it) are kept in --out; --from solves again from them. A placement the
    photographs do not determine (a symmetric shape with symmetric colours) is written and marked
    ambiguous. Exit status 3, as plan's, when a region can no longer get its samples. Details:
    docs/placement.md.

    \b
    Examples:
      hlr-lab register --plan plan.json --rig rig.toml -o placed.json
      hlr-lab acquire --plan placed.json --rig rig.toml
      hlr-lab register --plan plan.json --sim --object-offset 12,-8,200 -o placed.json
      hlr-lab register --plan plan.json --rig rig.toml --from placed-photographs-20261204-2130 -o placed.json
    """
    for given, option in ((scene_path, "--scene"), (object_offset, "--object-offset")):
        if given is not None and not sim:
            raise InputError("describes the simulated world: use it with --sim", field=option)
    if from_dir is not None and out is not None:
        raise InputError("--from reads the photographs of --out: give one of them", field="--out")
    rig = believed_rig(rig_path, sim, true_rig)
    folder = from_dir or out or default_folder(output)
    with contextlib.ExitStack() as stack:  # the simulated world, when there is one, outlives the photographs
        links = Links()
        if sim and from_dir is None:  # the simulator is reached only from the command line
            from worlds.plan_world import ObjectOffset, sim_links

            offset = None if object_offset is None else ObjectOffset.from_option(object_offset)
            links = sim_links(
                stack, rig, read_plan(plan_path), plan_path, scene_path, true_rig, speed_factor, offset
            )
        with pose_progress(console, VIEWS * len(registration_lamps(rig))) as show:
            done = register_plan(
                plan_path, rig, folder, output, links=links, solve_only=from_dir is not None,
                progress=lambda what: console.print(escape(what)), on_step=show,
                on_start=lambda resumed: console.print(
                    f"{'resuming' if resumed else 'photographing into'} {escape(str(folder))}"),
            )  # fmt: skip
    show_registered(done)
    if done.uncovered:
        raise SystemExit(EXIT_UNCOVERED)


def show_registered(done: Registered) -> None:
    """Print where the object lies, how certain, and what was written."""
    for line in registration_lines(done):
        console.print(line, soft_wrap=True)
