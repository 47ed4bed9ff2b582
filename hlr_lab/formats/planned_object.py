"""The object a plan was made for: its mesh, found from the plan's reference and checked by sha256, and
placed on the turntable as the plan placed it. Acquisition, the simulated world and fitting all start
from here, so a mesh that changed after planning is refused in one place."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.files import as_triple
from hlr_lab.formats.plan import PlanFile
from hlr_lab.object.mesh import FACE_SAMPLES, ColouredMesh, load_mesh, sample_texture, texture_sha256
from hlr_lab.object.procedural import BUILTIN_PREFIX, builtin_object
from hlr_lab.object.raycast import PixelSurface
from hlr_lab.object.segment import Region, Segmentation


def load_planned_mesh(plan: PlanFile, plan_path: Path) -> ColouredMesh:
    """The plan's mesh in its own frame; paths in the plan are relative to the plan file."""
    ref = plan.object.mesh
    if ref.startswith(BUILTIN_PREFIX):
        mesh = builtin_object(ref).mesh
    else:
        texture = None if plan.object.texture is None else plan_path.parent / plan.object.texture
        mesh = load_mesh(plan_path.parent / ref, texture)
    if mesh.sha256 != plan.object.sha256:
        raise InputError(
            f"the mesh {ref} has changed since the plan was made (sha256 differs); plan again",
            path=plan_path,
            field="object.sha256",
        )
    if plan.object.texture_sha256 is not None and texture_sha256(mesh) != plan.object.texture_sha256:
        raise InputError(
            f"the texture of {ref} has changed since the plan was made (or is not found any more): its regions "
            "are not the plan's; plan again",
            path=plan_path,
            field="object.texture_sha256",
        )
    _all_faces_in_regions(plan, plan_path, len(mesh.faces))
    return mesh


def _all_faces_in_regions(plan: PlanFile, plan_path: Path, faces: int) -> None:
    """Refuse a plan whose regions do not hold every face of its mesh (a region taken out of the plan: its
    pixels would be fitted as whichever neighbour's colour is nearest). Plans that do not record their
    regions' faces (0) are not checked."""
    held = sum(r.faces for r in plan.object.regions)
    if held and held != faces:
        raise InputError(
            f"its regions hold {held} faces, the mesh has {faces}: a region was taken out of (or added to) the "
            "plan by hand; plan again (hlr-lab plan) to change the regions",
            path=plan_path,
            field="object.regions",
        )


def mesh_to_turntable(plan: PlanFile) -> np.ndarray:
    """4×4: the plan's placement of the mesh on the turntable (identity for old plans without one)."""
    return np.array(plan.object.mesh_to_turntable or np.eye(4), dtype=np.float64)


def nominal_placement(plan: PlanFile) -> np.ndarray:
    """4×4: where the plan's object was assumed to lie before its placement was measured (the placement
    record's ``nominal_mesh_to_turntable``), else the plan's own placement."""
    record = plan.object.placement
    if record is None:
        return mesh_to_turntable(plan)
    return np.array(record.nominal_mesh_to_turntable, dtype=np.float64)


def placement_line(plan: PlanFile) -> str:
    """One line saying how the plan knows where its object lies: measured (when, how well, how far from
    where it was assumed), measured with its turn ambiguous (why), or assumed."""
    r = plan.object.placement
    if r is None or r.status == "assumed":
        return (
            "assumed: the object is taken to lie exactly where the plan puts it (its placement was never "
            "measured: hlr-lab register measures it)"
        )
    shift = r.offset_shift_mm or [0.0, 0.0, 0.0]
    measured = (
        f"measured {r.date} by {r.method} (outline {r.residual_px or 0:.2f} px RMS): "
        f"{float(np.hypot(shift[0], shift[1])):.1f} mm and {r.offset_turn_deg or 0:+.1f}° from where the plan "
        "first put it"
    )
    return measured if r.status == "measured" else f"{measured}; its turn is ambiguous: {r.why}"


def planned_segmentation(plan: PlanFile, mesh: ColouredMesh) -> Segmentation:
    """The plan's regions on ``mesh`` as the planner takes them: each face's region
    (:func:`face_regions`), each vertex's the region of a face it belongs to, the regions' records as the
    plan keeps them. What planning the object again (for a measured placement) starts from, so that its
    regions stay the plan's."""
    face_labels = face_regions(plan, mesh)
    vertex_labels = np.zeros(len(mesh.vertices), np.int64)
    vertex_labels[mesh.faces.reshape(-1)] = np.repeat(face_labels, 3)
    regions = [Region(r.id, r.material, as_triple(r.color), r.vertices, r.faces, r.area_m2)
               for r in plan.object.regions]  # fmt: skip
    return Segmentation(vertex_labels, face_labels, regions, np.nan, False, np.nan)


def region_ids(plan: PlanFile) -> np.ndarray:
    """(R,) the plan's region ids, in the order of :func:`palette`."""
    return np.array([r.id for r in plan.object.regions], np.int64)


def palette(plan: PlanFile) -> np.ndarray:
    """(R, 3) float64 the plan's region colours (8-bit sRGB)."""
    return np.array([r.color for r in plan.object.regions], np.float64)


def nearest_region(plan: PlanFile, colours: np.ndarray) -> np.ndarray:
    """(N, 3) sRGB8 colours → (N,) the id of the plan region whose colour is nearest."""
    p = palette(plan)
    d2 = ((np.asarray(colours, np.float64)[:, None, :] - p[None]) ** 2).sum(axis=2)
    return region_ids(plan)[np.argmin(d2, axis=1)]


def face_regions(plan: PlanFile, mesh: ColouredMesh) -> np.ndarray:
    """(F,) region id per face: a vertex-coloured face's mean corner colour's nearest region; a textured
    face's most common region among the texels at :data:`FACE_SAMPLES` (a face that a region border
    crosses goes to the region that covers most of it)."""
    if mesh.vertex_colours is not None:
        return nearest_region(plan, mesh.vertex_colours[mesh.faces].astype(np.float64).mean(axis=1))
    if mesh.texture is None or mesh.corner_uv is None:
        raise InputError("the mesh has neither vertex colours nor a texture: it has no regions")
    uv = np.einsum("sj,fjk->fsk", FACE_SAMPLES, mesh.corner_uv)  # (F, S, 2)
    samples = texel_regions(plan, mesh.texture, uv.reshape(-1, 2)).reshape(len(mesh.faces), len(FACE_SAMPLES))
    ids = region_ids(plan)
    votes = (samples[:, :, None] == ids[None, None, :]).sum(axis=1)  # (F, R)
    return ids[np.argmax(votes, axis=1)]


def texel_regions(plan: PlanFile, texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N,) region id of the texel of ``texture`` (H, W, 3) sRGB8 at each of ``uv`` (N, 2), wrapped
    (row 0 is the top: v = 1)."""
    texels = sample_texture(texture, uv)[:, :3].astype(np.int64)
    # a texture has far fewer colours than texels: each distinct colour is matched once
    keys, inverse = np.unique((texels[:, 0] << 16) | (texels[:, 1] << 8) | texels[:, 2], return_inverse=True)
    distinct = np.stack([keys >> 16, (keys >> 8) & 255, keys & 255], axis=1)
    return nearest_region(plan, distinct)[inverse.reshape(-1)]


def surface_regions(plan: PlanFile, mesh: ColouredMesh, surface: PixelSurface) -> np.ndarray:
    """(N,) region id at each hit of ``surface`` (−1 on a miss): from the texture at the hit's UV when
    the mesh is textured (region borders may cross faces), else from the face's colour."""
    out = np.full(len(surface.face), -1, np.int64)
    hit = surface.hit
    if not hit.any():
        return out
    face = surface.face[hit]
    if mesh.texture is None or mesh.corner_uv is None:
        out[hit] = face_regions(plan, mesh)[face]
        return out
    uv = np.einsum("ij,ijk->ik", surface.barycentric[hit], mesh.corner_uv[face])
    out[hit] = texel_regions(plan, mesh.texture, uv)
    return out
