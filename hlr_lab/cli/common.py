"""What several commands share: mesh and rig options (the consoles: :mod:`hlr_lab.cli.console`; the
tables: :mod:`hlr_lab.display`)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from hlr_lab.errors import InputError
from hlr_lab.rig.file import Rig, load_rig, sim_rig
from hlr_lab.session.lamp import LampWatch
from hlr_lab.session.outputs import has_control_character


class PathOption(click.Path):
    """A path option that refuses an empty name (``--out ''`` would make the current folder the session)
    and a name with a control character (a line break written into a file that names it breaks that file)."""

    def convert(self, value, param, ctx):
        if isinstance(value, str) and not value.strip():
            self.fail("an empty path names nothing: give a file or folder", param, ctx)
        if isinstance(value, str) and has_control_character(value):
            self.fail(
                f"{value!r} has a control character (a line break, a tab, …): give a plain name", param, ctx
            )
        return super().convert(value, param, ctx)


FILE = PathOption(dir_okay=False, path_type=Path)  # an option naming a file (that need not exist yet)
FOLDER = PathOption(file_okay=False, path_type=Path)  # an option naming a folder
ANY_PATH = PathOption(path_type=Path)  # a file or a folder (export: a Mitsuba scene is a folder)


def mesh_options(f):
    """``--mesh FILE|builtin:NAME`` (required) and ``--texture FILE``: the object's mesh and its colours."""
    f = click.option("--texture", type=FILE, help="Texture image for an OBJ whose UVs do not reference one.")(
        f
    )
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
    scale = click.option(
        "--scale", type=Finite(min=0, min_open=True), default=1.0, help="Mesh units → metres."
    )
    up = click.option(
        "--up", default="z", help="Mesh axis that points up on the turntable (y for most scans)."
    )
    return up(scale(f))


def output_option(what: str):
    """``-o/--output FILE`` (required): where the command writes ``what``."""
    return click.option("-o", "--output", type=FILE, required=True, help=f"Where to write {what}.")


def resolve_rig(rig_path: Path | None, use_sim: bool) -> Rig:
    """The rig of ``--rig FILE`` or ``--sim`` (exactly one of them), for commands that only read it."""
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
        return click.option("--rig", "rig_path", type=FILE, help="Rig file (rig.toml).")(f)

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


def speed_factor_option(subject: str, default: float = 1.0):
    """``--speed-factor`` for commands that run the simulated rig (tests and demos run it fast)."""
    return click.option(
        "--speed-factor",
        type=Finite(min=0.01),
        default=default,
        help=f"{subject} time runs this much faster than real time.",
    )


def warm_up_options(before: str, note: str = "", *, as_calibrated: bool = False):
    """``--warm-up MINUTES`` and ``--warm-up-within PERCENT``: keep the lamp on ``before`` until it is
    stable (acquire and calibrate radiometric take the same figures; defaults: :class:`LampWatch`', or with
    ``as_calibrated`` no default: the run's :func:`~hlr_lab.session.lamp.lamp_watch_for` decides)."""
    within = click.option(
        "--warm-up-within", "warm_up_within", type=Finite(min=0.01, max=10), metavar="PERCENT",
        default=100 * LampWatch.stable_per_min,
        help="The warm-up ends when the lamp's output changes by less than this per minute; use one figure for "
        "acquire and calibrate radiometric (a tighter one waits longer and leaves the lamp nearer its warm output).",
    )  # fmt: skip
    default = (
        "; default: 30 where the rig's radiometric calibration saw the lamp 0.5 % or more below warm when "
        "first lit, else 0"
        if as_calibrated
        else ""
    )
    minutes = click.option(
        "--warm-up", "warm_up_min", type=Finite(min=0), metavar="MINUTES",
        default=None if as_calibrated else LampWatch.warm_up_s / 60, show_default=not as_calibrated,
        help=f"{before}, keep the lamp on until its output is stable (--warm-up-within), for at most MINUTES "
        f"(0: no wait){note}{default}.",
    )  # fmt: skip
    return lambda f: minutes(within(f))


class Numbers(click.ParamType):
    """``count`` finite numbers separated by commas (``2,-1.5,3``), as a tuple of floats."""

    name = "numbers"

    def __init__(self, count: int) -> None:
        self.count = count

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        try:
            numbers = tuple(float(part) for part in str(value).split(","))
        except ValueError:
            numbers = ()
        if len(numbers) != self.count or not all(math.isfinite(x) for x in numbers):
            self.fail(f"{value!r}: {self.count} finite numbers separated by commas are needed", param, ctx)
        return numbers


def object_offset_option(f):
    """``--object-offset DX_MM,DY_MM,YAW_DEG`` for commands that run the simulated world: its object moved
    off where it would lie, hlr-lab not told (``worlds.plan_world.ObjectOffset``)."""
    return click.option(
        "--object-offset",
        "object_offset",
        type=Numbers(3),
        metavar="DX_MM,DY_MM,YAW_DEG",
        help="With --sim: the simulated object lies off where the plan (or the scene's placed) puts it: "
        "turned YAW_DEG about the turntable axis, then moved DX_MM, DY_MM on the plate; hlr-lab is not told.",
    )(f)
