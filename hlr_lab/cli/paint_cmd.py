"""``hlr-lab paint``: any mesh → a vertex-coloured test object in K patches (what segment and plan need)."""

from __future__ import annotations

from pathlib import Path

import click

from hlr_lab.cli.common import FILE, output_option
from hlr_lab.cli.console import console
from hlr_lab.errors import InputError
from hlr_lab.object.mesh import load_mesh, write_vertex_coloured_ply
from hlr_lab.object.procedural import PALETTE, paint_patches
from hlr_lab.session.outputs import check_outputs, mesh_files


@click.command()
@click.option("--mesh", "mesh_path", required=True, type=FILE,
              help="Mesh (OBJ, PLY, glTF/GLB); its colours, if any, are replaced.")  # fmt: skip
@click.option("--regions", "k", type=click.IntRange(2, len(PALETTE)), default=8,
              help="How many patches, each its own colour.")  # fmt: skip
@click.option("--seed", type=click.IntRange(min=0), default=0, help="Another seed gives other patches.")
@output_option("the painted mesh (.ply, vertex colours)")
def paint(mesh_path: Path, k: int, seed: int, output: Path) -> int:
    """Paint a mesh in K spatially compact patches of distinct colours, for trying segment, plan and
    the simulated rig on a mesh that has no colours of its own (the patches are k-means clusters of
    the vertices; the colours are far apart in CIELAB).

    \b
    Examples:
      hlr-lab paint --mesh stanford-bunny.obj --regions 8 -o bunny8.ply
      hlr-lab segment --mesh bunny8.ply -o regions.json
    """
    if output.suffix.lower() != ".ply":
        raise InputError(
            "the painted mesh is written as PLY (vertex colours): name it *.ply", field="--output"
        )
    with console.status("loading the mesh…"):
        mesh = load_mesh(mesh_path)
    check_outputs([output], mesh_files(mesh), writes=[None])  # not over the mesh painted, nor into a session
    with console.status(f"painting {len(mesh.vertices):,} vertices in {k} patches…"):
        painted = paint_patches(mesh, k, seed=seed).mesh
    write_vertex_coloured_ply(output, painted)
    console.print(
        f"wrote {output}: {len(painted.vertices):,} vertices, {len(painted.faces):,} faces, {k} patches"
    )
    return 0
