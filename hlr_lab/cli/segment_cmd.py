"""``hlr-lab segment``: mesh colours → regions.json."""

from __future__ import annotations

import click

from hlr_lab.cli.common import Finite, mesh_options, output_option, region_table
from hlr_lab.cli.console import console
from hlr_lab.formats.regions import write_regions
from hlr_lab.object.segment import DEFAULT_DELTA_E, DEFAULT_MIN_FRAGMENT
from hlr_lab.object.segment import segment as segment_mesh
from hlr_lab.pipeline import load_object


def segmentation_options(f):
    f = click.option(
        "--min-fragment",
        type=Finite(0, 0.5),
        default=DEFAULT_MIN_FRAGMENT,
        show_default=True,
        help="Connected patches smaller than this fraction of the surface merge into a neighbour.",
    )(f)
    f = click.option(
        "--split-connected",
        is_flag=True,
        help="Make every connected patch its own region (default: same colour = one region).",
    )(f)
    f = click.option(
        "--delta-e",
        type=Finite(min=0.5),
        default=DEFAULT_DELTA_E,
        show_default=True,
        help="Colours closer than this CIELAB ΔE are one material (sets the region count).",
    )(f)
    return f


@click.command()
@mesh_options
@click.option(
    "--regions",
    "n_regions",
    type=click.IntRange(min=1),
    help="Exactly this many colour regions (overrides --delta-e).",
)
@segmentation_options
@output_option("regions.json")
def segment(mesh_spec, texture, n_regions, delta_e, split_connected, min_fragment, output) -> int:
    """Split the surface into same-colour regions (per-vertex and per-face labels).

    \b
    Examples:
      hlr-lab segment --mesh bunny8.ply -o regions.json
      hlr-lab segment --mesh spot_triangulated.obj --texture spot_texture.png --regions 6 -o regions.json
    """
    with console.status("loading the mesh…"):
        mesh = load_object(mesh_spec, texture)
    with console.status(f"segmenting {len(mesh.vertices):,} vertices…"):
        seg = segment_mesh(
            mesh,
            delta_e=delta_e,
            n_materials=n_regions,
            split_connected=split_connected,
            min_fragment=min_fragment,
        )
    write_regions(output, mesh, seg, mesh_name=mesh_spec, regions_requested=n_regions)
    console.print(region_table(seg.regions, f"{seg.n_regions} regions of {mesh_spec}"))
    console.print(f"wrote {output}")
    return 0
