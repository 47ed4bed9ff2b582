"""Built-in procedural objects, so that planning and the demo run with no asset files.

``pebble``: a smooth, slightly lumpy body about 12 cm across whose six faces (±x, ±y, ±z of the
undeformed sphere) are painted in four colours: the ±x patches share one colour and so do ±z (the top,
and the bottom that rests on the table), so "same colour but not connected" is exercised.
:func:`paint_patches` colours any mesh in K spatial patches (used to give the Stanford bunny the
paper's 8 regions).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.cluster.vq import kmeans2
from scipy.spatial import KDTree

from hlr_lab.errors import InputError
from hlr_lab.object.mesh import ColouredMesh, arrays_sha256

BUILTIN_PREFIX = "builtin:"

PALETTE = np.array(  # 8-bit sRGB, pairwise ΔE > 30
    [
        [200, 50, 40],
        [60, 160, 70],
        [50, 80, 190],
        [220, 190, 60],
        [235, 235, 230],
        [150, 60, 170],
        [40, 170, 180],
        [120, 80, 40],
        [240, 140, 170],
        [90, 90, 90],
        # more, for objects of many regions (each chosen farthest from those before it: ΔE ≥ 45)
        [0, 0, 255],
        [0, 255, 0],
        [255, 0, 255],
        [255, 0, 150],
        [210, 255, 0],
        [30, 0, 45],
        [180, 180, 255],
        [0, 255, 210],
    ],
    dtype=np.uint8,
)


@dataclass(frozen=True, eq=False)
class ProceduralObject:
    """mesh, and the truth it was painted with: material (V,) and patch (V,) per vertex."""

    mesh: ColouredMesh
    material: np.ndarray
    patch: np.ndarray


def pebble(subdivisions: int = 5, radius_m: float = 0.06) -> ProceduralObject:
    """builtin:pebble: a lumpy ellipsoid of half-axes about ``radius_m`` × (1, 0.85, 0.8) (m), centred on
    the origin (a plan sets it on the plate), four materials on six patches; an icosphere of
    ``subdivisions`` moved out."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = np.asarray(sphere.vertices)
    # low-frequency lumps keep curvature varied (highlights of all widths) but the surface smooth
    r = 1 + 0.08 * np.sin(3 * d[:, 0] + 1) * np.cos(2 * d[:, 1]) + 0.05 * d[:, 2] ** 2
    vertices = radius_m * d * r[:, None] * np.array([1.0, 0.85, 0.8])
    axis = np.argmax(np.abs(d), axis=1)
    patch = axis * 2 + (np.take_along_axis(d, axis[:, None], 1)[:, 0] < 0)  # +x −x +y −y +z −z → 0…5
    material = np.array([0, 0, 1, 2, 3, 3])[patch]
    faces, colours = np.asarray(sphere.faces, dtype=np.int64), PALETTE[material]
    mesh = ColouredMesh(vertices, faces, colours, sha256=arrays_sha256(vertices, faces, colours))
    return ProceduralObject(mesh, material, patch)


def paint_patches(
    mesh: ColouredMesh, k: int, *, seed: int = 0, among: np.ndarray | None = None
) -> ProceduralObject:
    """Colour ``mesh`` in ``k`` spatially compact patches, one colour each: k-means on the positions of
    the vertices selected by ``among`` (V,) bool (default all), every vertex joining the nearest centre."""
    if k > len(PALETTE):
        raise ValueError(f"at most {len(PALETTE)} distinct patch colours")
    pts = mesh.vertices if among is None else mesh.vertices[among]
    centres, _ = kmeans2(pts, k, rng=np.random.default_rng(seed), minit="++")
    patch = np.asarray(KDTree(centres).query(mesh.vertices)[1], dtype=np.intp)
    colours = PALETTE[patch]
    return ProceduralObject(
        ColouredMesh(
            mesh.vertices, mesh.faces, colours, sha256=arrays_sha256(mesh.vertices, mesh.faces, colours)
        ),
        patch,
        patch,
    )


BUILTINS = {"pebble": pebble}


def builtin_object(spec: str) -> ProceduralObject:
    """``builtin:NAME`` → the procedural object; unknown names are an input error listing the known ones."""
    name = spec.removeprefix(BUILTIN_PREFIX)
    if name not in BUILTINS:
        raise InputError(
            f"unknown built-in object {name!r}; known: " + ", ".join(BUILTIN_PREFIX + n for n in BUILTINS),
            field="--mesh",
        )
    return BUILTINS[name]()
