"""``hlr-lab segment``: mesh colours → regions.json."""

from __future__ import annotations

import click

from hlr_lab.cli.common import Finite, mesh_options, output_option
from hlr_lab.cli.console import console
from hlr_lab.display.regions import region_table
from hlr_lab.formats.regions import REGIONS_FORMAT, write_regions
from hlr_lab.object.segment import DEFAULT_DELTA_E, DEFAULT_MIN_FRAGMENT
from hlr_lab.object.segment import segment as segment_mesh
from hlr_lab.pipeline import load_object
from hlr_lab.session.outputs import check_outputs, mesh_files


def segmentation_options(f):
    """``--delta-e``, ``--split-connected`` and ``--min-fragment``: how the mesh's colours become regions
    (:func:`hlr_lab.object.segment.segment`; its defaults)."""
    delta_e = click.option("--delta-e", type=Finite(min=0.5), default=DEFAULT_DELTA_E,
                           help="Colours closer than this CIELAB ΔE are one material "
                           "(sets the region count).")  # fmt: skip
    split = click.option(
        "--split-connected",
        is_flag=True,
        help="Make every connected patch its own region (default: same colour = one region).",
    )
    fragment = click.option("--min-fragment", type=Finite(0, 0.5), default=DEFAULT_MIN_FRAGMENT,
                            help="Connected patches smaller than this fraction of the surface merge into "
                            "a neighbour.")  # fmt: skip
    return delta_e(split(fragment(f)))


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
    check_outputs([output], mesh_files(mesh), writes=[REGIONS_FORMAT])
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
