"""``hlr-lab plan``: mesh, regions and rig → plan.json with a coverage table."""

from __future__ import annotations

import math
from pathlib import Path

import click
import numpy as np
from rich.table import Table

from hlr_lab.cli.common import Finite, mesh_options, output_option, placement_options, resolve_rig, swatch
from hlr_lab.cli.console import console
from hlr_lab.cli.segment_cmd import segmentation_options
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import write_plan
from hlr_lab.formats.regions import read_regions
from hlr_lab.object.segment import Segmentation
from hlr_lab.object.segment import segment as segment_mesh
from hlr_lab.pipeline import load_object, plan_object
from hlr_lab.planning.planner import PlanResult, PlanSettings

EXIT_UNCOVERED = 3  # the plan was written but some regions cannot get their M samples
_MAX_POSE_COLUMNS = 10


def parse_views(text: str) -> list[float] | None:
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
    "--regions",
    "regions_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="regions.json from hlr-lab segment (default: segment here).",
)
@segmentation_options
@click.option(
    "--rig", "rig_path", type=click.Path(dir_okay=False, path_type=Path), help="Rig file (rig.toml)."
)
@click.option("--sim", is_flag=True, help="Plan for the built-in simulated rig.")
@click.option(
    "--theta-c",
    type=Finite(0.1, 45),
    default=5.0,
    show_default=True,
    help="Cone half-angle θc about the mirror direction, degrees.",
)
@click.option(
    "--min-samples",
    type=Finite(min=1),
    default=50,
    show_default=True,
    help="Highlight samples M each region needs (in the --count unit).",
)
@click.option(
    "--sphere-scale",
    type=Finite(min=0, min_open=True),
    help="Light sphere = K × the object's bounding sphere (the paper: 2) instead of the gantry arm: an "
    "analysis plan, which acquire refuses.",
)
@click.option(
    "--count",
    type=click.Choice(["pixels", "vertices"]),
    default="pixels",
    show_default=True,
    help="Count expected pixels (vertex footprints through the camera) or vertices (the paper).",
)
@click.option(
    "--criterion",
    type=click.Choice(["capped", "plain"]),
    default="capped",
    show_default=True,
    help="capped: a region counts only up to what it still needs; plain: the paper's count.",
)
@click.option(
    "--views",
    "views_text",
    default="auto",
    show_default=True,
    metavar="auto|DEG,DEG,…",
    help="Turntable angles the planner may use (auto: every --view-step degrees, 0 first).",
)
@click.option(
    "--view-step",
    type=Finite(1, 180),
    default=45.0,
    show_default=True,
    help="Spacing of the automatic turntable angles, degrees.",
)
@click.option(
    "--spacing",
    type=Finite(0.05, 5),
    default=0.5,
    show_default=True,
    help="Spacing of the candidate light positions on the sphere, degrees.",
)
@click.option(
    "--max-lights",
    type=click.IntRange(1, 1000),
    default=64,
    show_default=True,
    help="At most this many light positions per view (the plan stops there, covered or not).",
)
@click.option(
    "--max-view-angle",
    type=Finite(10, 89),
    default=80.0,
    show_default=True,
    help="Grazing limit: surfaces seen or lit beyond this angle from their normal do not count.",
)
@click.option("--no-shadows", is_flag=True, help="Do not ray-cast shadows (the paper did not).")
@placement_options
@output_option("plan.json")
def plan(
    mesh_spec,
    texture,
    regions_file,
    delta_e,
    split_connected,
    min_fragment,
    rig_path,
    sim,
    theta_c,
    min_samples,
    sphere_scale,
    count,
    criterion,
    views_text,
    view_step,
    spacing,
    max_lights,
    max_view_angle,
    no_shadows,
    up,
    scale,
    output,
) -> int:
    """Plan light positions that give every region M highlight samples.

    Exits with status 3 (after writing the plan) when some region cannot be covered; the table and
    plan.json say why.

    \b
    Examples:
      hlr-lab plan --mesh builtin:pebble --sim -o plan.json
      hlr-lab plan --mesh bunny.obj --up y --sim --sphere-scale 2 --views 0 --count vertices -o plan.json
      hlr-lab plan --mesh spot.obj --texture spot.png --scale 0.08 --up y --rig rig.toml -o plan.json
    """
    rig = resolve_rig(rig_path, sim)
    views = parse_views(views_text)
    with console.status("loading the mesh…"):
        mesh = load_object(mesh_spec, texture)
    if regions_file is not None:
        seg = read_regions(regions_file, mesh)
    else:
        with console.status("segmenting…"):
            seg = segment_mesh(
                mesh, delta_e=delta_e, split_connected=split_connected, min_fragment=min_fragment
            )
    settings = PlanSettings(
        theta_c_deg=theta_c,
        min_samples=min_samples,
        count=count,
        sphere_scale=sphere_scale,
        views_deg=views,
        view_step_deg=view_step,
        spacing_deg=spacing,
        max_view_angle_deg=max_view_angle,
        max_lights=max_lights,
        shadows=not no_shadows,
        criterion=criterion,
    )
    with console.status(
        f"planning on {rig.name} ({len(mesh.vertices):,} vertices, {seg.n_regions} regions)…"
    ):
        plan_file, result = plan_object(
            mesh, seg, rig, settings, mesh_spec=mesh_spec, plan_folder=output.parent, up=up, scale=scale
        )
    write_plan(output, plan_file)
    console.print(coverage_table(result, seg))
    _print_summary(result, output)
    return EXIT_UNCOVERED if result.uncovered else 0


def coverage_table(result: PlanResult, seg: Segmentation) -> Table:
    unit = result.settings.count
    t = Table(title=f"coverage ({unit}; M = {result.settings.min_samples:g})", title_justify="left")
    t.add_column("region", justify="right")
    t.add_column("colour (sRGB)")
    shown = result.lights[:_MAX_POSE_COLUMNS]
    for i, light in enumerate(shown):
        t.add_column(f"p{i:03d}\n{light.turntable_deg:g}°", justify="right")
    if len(result.lights) > len(shown):
        t.add_column("…", justify="right")
    t.add_column("total", justify="right")
    t.add_column("satisfied")
    for r in seg.regions:
        cells = [f"{light.expected[r.id]:.0f}" if light.expected[r.id] > 0 else "·" for light in shown]
        if len(result.lights) > len(shown):
            cells.append(f"{sum(light.expected[r.id] for light in result.lights[len(shown) :]):.0f}")
        ok = bool(result.satisfied[r.id])
        mark = "[green]yes[/]" if ok else f"[red]no[/]: {result.uncovered.get(r.id, '')}"
        t.add_row(str(r.id), swatch(r.colour), *cells, f"{result.coverage[r.id]:.0f}", mark)
    return t


def _print_summary(result: PlanResult, output: Path) -> None:
    by = result.lights_by_criterion
    crit = result.settings.criterion
    views = sorted({light.turntable_deg for light in result.lights})
    line = (
        f"{len(result.lights)} lights over {len(views)} turntable view(s) {', '.join(f'{v:g}°' for v in views)}; "
        f"sphere {result.sphere.radius:.3f} m ({result.sphere.source}); "
        f"{result.reachable:,} of {result.candidates:,} candidate positions reachable"
    )
    console.print(line)
    if result.sphere.source == "scale":
        console.print(
            f"[yellow]an analysis plan[/]: its lights are on a {result.sphere.radius:.3f} m sphere about the object "
            f"(--sphere-scale), not on the gantry's {result.sphere.gantry.arm_radius:.3f} m arm, so acquire "
            "refuses it; plan without --sphere-scale to measure on the rig"
        )
    other = [k for k in by if k != crit]
    if other:
        console.print(
            f"the {other[0]} count would need {by[other[0]]} lights (this plan: {crit}, {by[crit]})"
        )
    n_bad = int(np.sum(~result.satisfied))
    if n_bad:
        console.print(
            f"[yellow]{n_bad} region(s) cannot get their {result.settings.min_samples:g} samples; "
            "see 'uncovered' in the plan[/]"
        )
    console.print(f"wrote {output}")
