"""The regions of a segmentation, as ``segment`` and ``demo`` show them."""

from __future__ import annotations

from rich.table import Table

from hlr_lab.object.segment import Region


def swatch(colour: tuple[int, int, int]) -> str:
    """A patch of ``colour`` (sRGB, 0–255) and its three values, in rich markup."""
    r, g, b = colour
    return f"[on rgb({r},{g},{b})]    [/] {r:3d},{g:3d},{b:3d}"


def region_table(regions: list[Region], title: str) -> Table:
    """One row per region: id, material, colour, vertex and face counts, area (m²)."""
    t = Table(title=title, title_justify="left")
    for name in ("region", "material", "colour (sRGB)", "vertices", "faces", "area m²"):
        t.add_column(name, justify="right")
    for r in regions:
        t.add_row(
            str(r.id), str(r.material), swatch(r.colour), str(r.vertices), str(r.faces), f"{r.area_m2:.4g}"
        )
    return t
