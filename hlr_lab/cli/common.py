"""What several commands share: mesh and rig options, tables (the consoles: :mod:`hlr_lab.cli.console`)."""

from __future__ import annotations

import math
from pathlib import Path

import click
from rich.table import Table

from hlr_lab.errors import InputError
from hlr_lab.object.segment import Region
from hlr_lab.rig.file import Rig, load_rig, sim_rig


def mesh_options(f):
    f = click.option(
        "--texture",
        type=click.Path(dir_okay=False, path_type=Path),
        help="Texture image for an OBJ whose UVs do not reference one.",
    )(f)
    f = click.option(
        "--mesh",
        "mesh_spec",
        required=True,
        metavar="FILE",
        help="Mesh (OBJ, PLY, glTF/GLB) with vertex colours or a texture, or builtin:pebble.",
    )(f)
    return f


def placement_options(f):
    """``--up`` and ``--scale``: how the mesh stands on the turntable (its up axis; its units)."""
    f = click.option("--scale", type=Finite(min=0, min_open=True), default=1.0, show_default=True,
                     help="Mesh units → metres.")(f)  # fmt: skip
    return click.option("--up", default="z", show_default=True,
                        help="Mesh axis that points up on the turntable (y for most scans).")(f)  # fmt: skip


def output_option(what: str):
    return click.option(
        "-o",
        "--output",
        type=click.Path(dir_okay=False, path_type=Path),
        required=True,
        help=f"Where to write {what}.",
    )


def resolve_rig(rig_path: Path | None, use_sim: bool) -> Rig:
    if rig_path is not None and use_sim:
        raise InputError("give either --rig FILE or --sim, not both", field="--rig")
    if rig_path is None and not use_sim:
        raise InputError(
            "which rig? give --rig rig.toml for a real rig, or --sim for the built-in simulated rig",
            field="--rig",
        )
    if rig_path is None:
        return sim_rig()
    return load_rig(rig_path)


def believed_rig(rig_path: Path | None, use_sim: bool, true_rig: str | None = None) -> Rig:
    """The rig hlr-lab works with: the file given, else with ``use_sim`` the built-in simulated rig.
    Unlike :func:`resolve_rig`, a rig file may come with ``--sim``: the simulated world then takes the
    file's geometry (or ``--true-rig``'s), and its endpoints replace the file's links. ``--true-rig``
    without ``--sim`` is refused."""
    if true_rig is not None and not use_sim:
        raise InputError("describes the simulated world: use it with --sim", field="--true-rig")
    if rig_path is not None:
        return load_rig(rig_path)
    return resolve_rig(None, use_sim)


def rig_options(sim_help: str):
    """``--rig FILE``, ``--sim`` and ``--true-rig`` for commands that drive a rig (read them with
    :func:`believed_rig`)."""

    def apply(f):
        f = true_rig_option(f)
        f = click.option("--sim", is_flag=True, help=sim_help)(f)
        return click.option(
            "--rig", "rig_path", type=click.Path(dir_okay=False, path_type=Path), help="Rig file (rig.toml)."
        )(f)

    return apply


def true_rig_option(f):
    """``--true-rig`` for commands that run the simulated world."""
    return click.option(
        "--true-rig",
        "true_rig",
        metavar="FILE|builtin:NAME",
        help="Build the simulated world from this rig file (the rig as it really is, e.g. "
        "builtin:bench-offsets), while hlr-lab keeps believing its own rig file.",
    )(f)


class Finite(click.FloatRange):
    """A number option within a range that also refuses NaN and ±inf (a plain FloatRange lets NaN through:
    every comparison with it is false)."""

    name = "finite number"

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


def swatch(colour: tuple[int, int, int]) -> str:
    r, g, b = colour
    return f"[on rgb({r},{g},{b})]    [/] {r:3d},{g:3d},{b:3d}"


def region_table(regions: list[Region], title: str) -> Table:
    t = Table(title=title, title_justify="left")
    for name in ("region", "material", "colour (sRGB)", "vertices", "faces", "area m²"):
        t.add_column(name, justify="right")
    for r in regions:
        t.add_row(
            str(r.id), str(r.material), swatch(r.colour), str(r.vertices), str(r.faces), f"{r.area_m2:.4g}"
        )
    return t


def speed_factor_option(subject: str, default: float = 1.0):
    """``--speed-factor`` for commands that run the simulated rig (tests and demos run it fast)."""
    return click.option(
        "--speed-factor",
        type=Finite(min=0.01),
        default=default,
        show_default=True,
        help=f"{subject} time runs this much faster than real time.",
    )
