"""``hlr-lab bench``: benchmarks that print figures."""

from __future__ import annotations

from pathlib import Path

import click

from hlr_lab.bench import PAPER_SETTINGS, mesh_label, nearest_neighbour_spacing_deg, run_plan_case
from hlr_lab.cli.common import console, out
from hlr_lab.sphere import directions_with_spacing


@click.group()
def bench() -> None:
    """Benchmarks that print figures (targets in the README)."""


@bench.command("plan")
@click.option(
    "--mesh",
    "mesh_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Mesh to plan on (default: the built-in pebble). The paper's: the Stanford bunny.",
)
@click.option("--up", default="z", show_default=True, help="Mesh axis that points up (y for the bunny).")
@click.option("--scale", type=float, default=1.0, show_default=True, help="Mesh units → metres.")
@click.option(
    "--large",
    "min_vertices",
    type=click.IntRange(min=0),
    default=1_000_000,
    show_default=True,
    help="Also plan on the mesh subdivided to at least this many vertices (0: skip).",
)
def bench_plan(mesh_path, up, scale, min_vertices) -> None:
    """Planning time and peak memory: the paper's 4.1 set-up (8 regions in view, sphere 2× the bounding
    sphere, θc = 5°, one view, candidate spacing 0.5°) on the mesh and on a ≥ 1 M-vertex subdivision.

    \b
    Example:
      hlr-lab bench plan --mesh ../shared/assets/stanford-bunny.obj --up y
    """
    spacing = nearest_neighbour_spacing_deg(directions_with_spacing(PAPER_SETTINGS.spacing_deg))
    console.print(
        f"candidate spacing: requested {PAPER_SETTINGS.spacing_deg}°, measured max nearest-neighbour "
        f"{spacing:.3f}°"
    )
    name = mesh_label(str(mesh_path) if mesh_path else None)
    cases = [(name, None if mesh_path is None else str(mesh_path), up, scale, 0)]
    if min_vertices:
        cases.append(
            (f"{name} subdivided", None if mesh_path is None else str(mesh_path), up, scale, min_vertices)
        )
    out.print("plan benchmark: one fresh process per case; mesh loading and segmentation excluded")
    for case in cases:
        with console.status(f"planning {case[0]}…"):
            f = run_plan_case(*case)
        stages = ", ".join(f"{k} {v:.2f}" for k, v in f.stages.items())
        out.print(f"{f.case}: {f.vertices:,} vertices, {f.regions} regions", soft_wrap=True, markup=False)
        out.print(
            f"  lights {f.lights} (plain count {f.lights_plain}), uncovered regions {f.uncovered}",
            soft_wrap=True,
            markup=False,
        )
        out.print(f"  plan time {f.plan_s:.2f} s  [{stages}]", soft_wrap=True, markup=False)
        out.print(
            f"  memory: RSS {f.rss_before_mb:.0f} MB before planning, peak RSS {f.rss_peak_plan_mb:.0f} MB "
            "while planning",
            soft_wrap=True,
            markup=False,
        )
