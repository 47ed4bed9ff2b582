"""``hlr-lab export``: materials.json on the mesh → OBJ + MTL, glTF 2.0 or a Mitsuba 3 scene."""

from __future__ import annotations

import click

from hlr_lab.cli.common import ANY_PATH, FILE, mesh_options
from hlr_lab.cli.console import console
from hlr_lab.pipeline import EXPORT_FORMATS, export_materials, load_object


@click.command()
@click.argument("materials_path", metavar="MATERIALS", type=FILE)
@mesh_options
@click.option(
    "--regions",
    "regions_file",
    type=FILE,
    help="regions.json the materials were fitted with (default: segment the mesh again).",
)
@click.option("--format", "fmt", type=click.Choice(sorted(EXPORT_FORMATS)), required=True)
@click.option(
    "-o",
    "--output",
    type=ANY_PATH,
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
    mesh = load_object(mesh_spec, texture)
    written, stand_ins = export_materials(materials_path, mesh, fmt, output, regions_path=regions_file,
                                          mesh_spec=mesh_spec)  # fmt: skip
    for path in written:
        console.print(f"wrote {path}")
    if stand_ins:
        console.print(
            f"[yellow]warning:[/] region(s) {', '.join(map(str, stand_ins))} had no fitted material: exported with "
            "their colour as a diffuse-only stand-in, named region_N_stand_in_not_measured",
            soft_wrap=True,
        )
    return 0
