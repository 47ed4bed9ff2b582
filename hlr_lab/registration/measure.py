"""Where the plan's object lies, from its registration photographs: the outlines first, then — when they
leave the turn about the axis open — the colour regions the mesh knows (:mod:`hlr_lab.placement.solve`);
and the placement record a plan keeps of it (docs/placement.md)."""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from hlr_lab.errors import InputError, PlacementError
from hlr_lab.formats.plan import PlacementRecord, PlanFile
from hlr_lab.formats.planned_object import (
    load_planned_mesh,
    mesh_to_turntable,
    nominal_placement,
    palette,
    region_ids,
    surface_regions,
)
from hlr_lab.geometry.colour import srgb8_to_linear
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.raycast import PixelSurface
from hlr_lab.placement.faces import register_on_faces
from hlr_lab.placement.photographs import ObservedView, observe
from hlr_lab.placement.pose import PlacementFrame
from hlr_lab.placement.solve import Outlines, Registration, turn_angles, turn_by_colours
from hlr_lab.registration.views import Photographs


@dataclass(frozen=True, eq=False)
class Measured:
    """A registration's outcome: where the object lies (``found``), the outlines it was fitted on (the
    views as observed, the mesh in its own frame), and the folder of the photographs."""

    found: Registration
    outlines: Outlines
    folder: Path
    face: str | None = None  # resting on another face than the plan's: which (faces.Rest.describe)

    @property
    def observed(self) -> list[ObservedView]:
        return self.outlines.views

    @property
    def mesh(self) -> ColouredMesh:
        return self.outlines.mesh


def measure_placement(
    plan: PlanFile,
    plan_path: Path,
    photographs: Photographs,
    folder: Path,
    *,
    progress: Callable[[str], None] = lambda _: None,
) -> Measured:
    """Where ``plan``'s object lies, from ``photographs`` (taken in ``folder``). Refuses photographs of
    another object; :class:`PlacementError` when the object is not found as the plan's mesh within the
    search range (:func:`hlr_lab.placement.solve.register`)."""
    if photographs.plan.object.sha256 != plan.object.sha256:
        raise InputError(
            "holds the photographs of another object (its registration plan's mesh is not this plan's): give "
            "the folder of this object's registration, or register it again",
            path=folder,
        )
    mesh = load_planned_mesh(plan, plan_path)
    nominal = mesh_to_turntable(plan)
    progress("reading the outlines…")
    observed = [
        observe(v, photographs.sensor, where=f"{folder}: the view at turntable {v.turntable_deg:g}°")
        for v in photographs.views
    ]
    progress("searching every turn about the axis…")
    rest = register_on_faces(mesh, photographs.rig.camera, nominal, observed, plan.object.scale)
    found = rest.found
    if found.ambiguous is not None:
        found = _turned_by_colours(plan, mesh, rest.outlines, found, progress)
    return Measured(found, rest.outlines, folder, rest.describe())


def _turned_by_colours(
    plan: PlanFile,
    mesh: ColouredMesh,
    outlines: Outlines,
    found: Registration,
    progress: Callable[[str], None],
) -> Registration:
    """The outlines' placement turned as the colour regions say, or still ambiguous (and why)."""
    if len(plan.object.regions) < 2:
        return replace(found, ambiguous=f"{found.ambiguous}; the object has one colour, which cannot fix it")
    progress("the outline leaves the turn open: reading the colours…")
    ids = region_ids(plan)
    linear = srgb8_to_linear(palette(plan))  # (R, 3)
    expected = np.zeros((int(ids.max()) + 1, 2))
    expected[ids] = linear[:, :2] / np.maximum(linear.sum(axis=1, keepdims=True), 1e-9)

    def regions(surface: PixelSurface) -> np.ndarray:
        return surface_regions(plan, mesh, surface)

    try:
        return turn_by_colours(outlines, found, regions, expected)
    except PlacementError as exc:
        return replace(found, ambiguous=f"{found.ambiguous}; {exc}")


def placement_record(measured: Measured, plan: PlanFile) -> PlacementRecord:
    """The plan's record of the measured placement: its errors, and its offset from where the object was
    assumed to lie before any registration (:func:`~hlr_lab.formats.planned_object.nominal_placement`)."""
    found = measured.found
    nominal = nominal_placement(plan)
    offset = PlacementFrame.about(measured.mesh.vertices, nominal).params(found.mesh_to_turntable)
    turn, tilt = turn_angles(offset)
    se = np.minimum(found.se, 999.0)  # an undetermined turn's error is "huge", not 10¹²
    return PlacementRecord(
        status="ambiguous" if found.ambiguous else "measured",
        method=("outlines+colours" if found.turn_from == "colours" else "outlines")
        + (f"; {measured.face}" if measured.face else ""),
        date=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        nominal_mesh_to_turntable=[[round(float(v), 9) for v in row] for row in nominal],
        photographs=str(measured.folder.resolve()),
        residual_px=round(found.residual_px, 3),
        outline_seen=round(found.outline_seen, 4),
        outline_offset_px=round(found.outline_offset_px, 3),
        se_shift_mm=_rounded(se[3:]),
        se_rotation_deg=_rounded(se[:3]),
        offset_shift_mm=_rounded(offset[3:]),
        offset_rotation_deg=_rounded(offset[:3]),
        offset_turn_deg=round(turn, 4),
        offset_tilt_deg=round(tilt, 4),
        why=found.ambiguous,
    )


def _rounded(v: np.ndarray) -> list[float]:
    return [round(float(x), 4) for x in v]
