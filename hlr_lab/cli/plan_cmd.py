"""``hlr-lab plan``: mesh, regions and rig → plan.json with a coverage table."""

from __future__ import annotations

import math

import click

from hlr_lab.cli.common import FILE, Finite, mesh_options, output_option, placement_options, resolve_rig
from hlr_lab.cli.console import console
from hlr_lab.cli.segment_cmd import segmentation_options
from hlr_lab.display.plan import coverage_table, plan_summary
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PLAN_FORMAT, write_plan
from hlr_lab.formats.regions import read_regions
from hlr_lab.object.segment import segment as segment_mesh
from hlr_lab.pipeline import load_object, plan_object
from hlr_lab.planning.planner import MAX_OPTIMUM_BUDGET_S, PlanSettings
from hlr_lab.session.outputs import check_outputs, mesh_files

EXIT_UNCOVERED = 3  # the plan was written but some regions cannot get their M samples


def setting(flags: str, field: str, kind: click.ParamType | None, help: str):
    """An option that sets :class:`PlanSettings`' ``field`` (its default, shown in --help, is the field's)."""
    return click.option(flags, field, type=kind, default=getattr(PlanSettings, field), help=help)


def parse_views(text: str) -> list[float] | None:
    """``--views``: None for "auto", else the turntable angles in degrees (each within ±360)."""
    if text.strip().lower() == "auto":
        return None
    try:
        views = [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise InputError(
            f"{text!r} is not 'auto' or a comma-separated list of angles in degrees", field="--views"
        ) from exc
    if not views:
        raise InputError("give at least one angle, or 'auto'", field="--views")
    bad = [v for v in views if not (math.isfinite(v) and -360.0 <= v <= 360.0)]
    if bad:
        raise InputError(f"{bad[0]:g} is not a turntable angle in degrees (−360 … 360)", field="--views")
    return views


@click.command()
@mesh_options
@click.option(
    "--regions", "regions_file", type=FILE, help="regions.json from hlr-lab segment (default: segment here)."
)
@segmentation_options
@click.option("--rig", "rig_path", type=FILE, help="Rig file (rig.toml).")
@click.option("--sim", is_flag=True, help="Plan for the built-in simulated rig.")
@setting(
    "--theta-c", "theta_c_deg", Finite(0.1, 45), "Cone half-angle θc about the mirror direction, degrees."
)
@setting(
    "--min-samples",
    "min_samples",
    Finite(min=1),
    "Highlight samples M each region needs (in the --count unit).",
)
@setting(
    "--min-diffuse",
    "min_diffuse",
    Finite(min=0),
    "Diffuse-only samples (outside every highlight cone; Rd is fitted from them) each region needs, in "
    "the --count unit; lights are added where the highlight lights leave a region short (0: not planned).",
)
@setting(
    "--sphere-scale",
    "sphere_scale",
    Finite(min=0, min_open=True),
    "Light sphere = K × the object's "
    "bounding sphere (the paper: 2) instead of the gantry arm: an analysis plan, which acquire refuses.",
)
@setting(
    "--count",
    "count",
    click.Choice(["pixels", "vertices"]),
    "Count expected pixels (vertex footprints through the camera) or vertices (the paper).",
)
@setting(
    "--criterion",
    "criterion",
    click.Choice(["capped", "plain"]),
    "capped: a region counts only up to what it still needs; plain: the paper's count.",
)
@click.option(
    "--views",
    "views_deg",
    default="auto",
    metavar="auto|DEG,DEG,…",
    callback=lambda _c, _p, text: parse_views(text),
    help="Turntable angles the planner may use (auto: every --view-step degrees, 0 first).",
)
@setting(
    "--view-step", "view_step_deg", Finite(1, 180), "Spacing of the automatic turntable angles, degrees."
)
@setting(
    "--spacing",
    "spacing_deg",
    Finite(0.05, 5),
    "Spacing of the candidate light positions on the sphere, degrees.",
)
@setting(
    "--max-lights",
    "max_lights",
    click.IntRange(1, 1000),
    "At most this many light positions per view (the plan stops there, covered or not).",
)
@setting(
    "--max-view-angle",
    "max_view_angle_deg",
    Finite(10, 89),
    "Grazing limit: surfaces seen or lit beyond this angle from their normal do not count.",
)
@setting("--shadows/--no-shadows", "shadows", None, "Ray-cast shadows (the paper did not).")
@setting(
    "--optimum-budget",
    "optimum_budget_s",
    Finite(0, MAX_OPTIMUM_BUDGET_S),
    "A guard, in seconds, on the integer programme that looks for fewer lights than the greedy: its own work "
    "limits end it first, so that a plan is the same on any machine (0: the LP bound only).",
)
@placement_options
@output_option("plan.json")
def plan(mesh_spec, texture, regions_file, delta_e, split_connected, min_fragment, rig_path, sim, up, scale,
         output, **settings) -> int:  # fmt: skip
    """Plan as few light positions as it can that give every region M highlight samples.

    The greedy (both criteria) and an integer programme within --optimum-budget each choose lights; the
    plan keeps the fewest and prints how far that can be from the fewest possible (a lower bound).

    Exits with status 3 (after writing the plan) when some region cannot be covered; the table and
    plan.json say why.

    \b
    Examples:
      hlr-lab plan --mesh builtin:pebble --sim -o plan.json
      hlr-lab paint --mesh stanford-bunny.obj --regions 8 -o bunny8.ply   # the paper's set-up:
      hlr-lab plan --mesh bunny8.ply --up y --sim --sphere-scale 2 --views 0 --count vertices -o plan.json
      hlr-lab plan --mesh spot.obj --texture spot.png --scale 0.08 --up y --rig rig.toml -o plan.json
    """
    rig = resolve_rig(rig_path, sim)
    with console.status("loading the mesh…"):
        mesh = load_object(mesh_spec, texture)
    check_outputs([output], [*mesh_files(mesh), regions_file, rig_path], writes=[PLAN_FORMAT])
    if regions_file is not None:
        seg = read_regions(regions_file, mesh)
    else:
        with console.status("segmenting…"):
            seg = segment_mesh(
                mesh, delta_e=delta_e, split_connected=split_connected, min_fragment=min_fragment
            )
    plan_settings = PlanSettings(**settings)  # the options are named as its fields
    with console.status(
        f"planning on {rig.name} ({len(mesh.vertices):,} vertices, {seg.n_regions} regions)…"
    ):
        plan_file, result = plan_object(
            mesh, seg, rig, plan_settings, mesh_spec=mesh_spec, plan_folder=output.parent, up=up, scale=scale
        )
    write_plan(output, plan_file)
    console.print(coverage_table(result, seg))
    for line in plan_summary(result, output):
        console.print(line)
    return EXIT_UNCOVERED if result.uncovered else 0
