"""``hlr-lab export``: materials.json on the mesh → OBJ + MTL, glTF 2.0 or a Mitsuba 3 scene."""

from __future__ import annotations

from pathlib import Path

import click

from hlr_lab.cli.common import load_coloured_mesh, mesh_options
from hlr_lab.cli.console import console
from hlr_lab.errors import InputError
from hlr_lab.export.gltf import write_gltf
from hlr_lab.export.mitsuba import write_mitsuba
from hlr_lab.export.obj import write_obj
from hlr_lab.export.regions import region_parts
from hlr_lab.formats.materials import read_materials
from hlr_lab.formats.regions import read_regions
from hlr_lab.segment import segment

WRITERS = {"obj": (write_obj, ".obj"), "gltf": (write_gltf, ".glb"), "mitsuba": (write_mitsuba, "")}


@click.command()
@click.argument("materials_path", metavar="MATERIALS", type=click.Path(dir_okay=False, path_type=Path))
@mesh_options
@click.option(
    "--regions",
    "regions_file",
    type=click.Path(dir_okay=False, path_type=Path),
    help="regions.json the materials were fitted with (default: segment the mesh again).",
)
@click.option("--format", "fmt", type=click.Choice(sorted(WRITERS)), required=True)
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    required=True,
    help="File to write (obj: .obj with its .mtl beside it; gltf: .glb) or, for mitsuba, a folder.",
)
def export(materials_path, mesh_spec, texture, regions_file, fmt, output) -> int:
    """Write the fitted materials on the mesh for other tools.

    \b
    Examples:
      hlr-lab export materials.json --mesh bunny8.ply --regions regions.json --format gltf -o bunny.glb
      hlr-lab export materials.json --mesh builtin:pebble --format mitsuba -o pebble-scene/
    """
    materials = read_materials(materials_path)
    mesh = load_coloured_mesh(mesh_spec, texture)
    if materials.sha256 and mesh.sha256 and materials.sha256 != mesh.sha256:
        raise InputError(
            f"made for another mesh ({materials.mesh}) than {mesh_spec}", path=materials_path, field="sha256"
        )
    seg = read_regions(regions_file, mesh) if regions_file else segment(mesh)
    parts = region_parts(mesh, seg, materials, source=str(materials_path))
    writer, suffix = WRITERS[fmt]
    if suffix and output.suffix.lower() != suffix:
        raise InputError(f"a {fmt} export is written to a {suffix} file", field="--output")
    for path in writer(output, parts):
        console.print(f"wrote {path}")
    return 0
