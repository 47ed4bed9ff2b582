"""``hlr-lab demo``: the whole instrument on the simulated rig in one command (:mod:`worlds.demo`)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path

import click
from rich.console import RenderableType
from rich.markup import escape

from hlr_lab.cli.common import (
    FILE,
    FOLDER,
    object_offset_option,
    placement_options,
    speed_factor_option,
    true_rig_option,
)
from hlr_lab.cli.console import console
from worlds.demo import run_demo
from worlds.plan_world import ObjectOffset


@click.command("demo")
@click.option(
    "--scene",
    "scene_path",
    type=FILE,
    help="A sim scene file: its mesh (with colours) is the object, its regions the true materials. "
    "Default: the built-in procedural multi-region object.",
)
@click.option(
    "--out",
    "out",
    type=FOLDER,
    default=Path("hlr-lab-demo"),
    help="Folder for everything the demo writes (a new one: the demo never overwrites).",
)
@placement_options
@true_rig_option
@object_offset_option
@speed_factor_option("Simulated", default=20.0)
def demo(scene_path: Path | None, out: Path, up: str, scale: float, true_rig: str | None,
         object_offset: tuple[float, float, float] | None, speed_factor: float) -> None:  # fmt: skip
    """Run the whole measurement on the simulated rig and compare the result with the truth.

    \b
    Steps (each does what the hlr-lab command of the same name does, with its defaults):
      segment → plan → acquire (simulated rig) → fit → report → export (OBJ, glTF, Mitsuba)

    \b
    Examples:
      hlr-lab demo
      hlr-lab demo --scene my-object/scene.toml --out demo-2
      hlr-lab demo --scene scan/scene.toml --up y --scale 0.001 --out demo-scan   # a y-up scan in mm
      hlr-lab demo --true-rig builtin:bench-offsets --out demo-3   # the rig is not its drawing
      hlr-lab demo --object-offset 2,-1.5,3 --out demo-4   # the object 2.5 mm off and turned 3°
    """
    offset = None if object_offset is None else ObjectOffset.from_option(object_offset)
    report = run_demo(out, _ConsoleDisplay(), scene_path, up=up, scale=scale, true_rig=true_rig,
                      speed_factor=speed_factor, offset=offset)  # fmt: skip
    console.print(f"report: [bold]{escape(str(report))}[/] — open it in a browser")


class _ConsoleDisplay:
    """The demo's steps as rules, its tables and lines, its long work as a status line."""

    def step(self, name: str, what: str) -> None:
        console.rule(escape(f"{name}: {what}"))

    def show(self, item: RenderableType) -> None:
        console.print(item)

    @contextlib.contextmanager
    def busy(self, what: str) -> Iterator[Callable[[str], None]]:
        with console.status(what) as status:
            yield status.update
