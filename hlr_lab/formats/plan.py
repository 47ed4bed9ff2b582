"""``plan.json`` (docs/formats.md): what ``hlr-lab acquire`` runs. The skeleton is fixed (other tools read it);
hlr-lab adds fields: the mesh → turntable placement, the sphere, the criterion, a summary.

``position_mesh_m`` and ``camera_position_mesh_m`` are in the mesh file's own frame and units (metres
unless ``object.scale`` ≠ 1), so a reader can check the plan against the mesh alone.
"""

from __future__ import annotations

import datetime as dt
import re
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator

from hlr_lab import __version__
from hlr_lab.files import OpenModel, read_format, write_json
from hlr_lab.formats.regions import RegionEntry
from hlr_lab.object.segment import Segmentation
from hlr_lab.planning.geometry import SphereSource
from hlr_lab.planning.planner import PlanResult

PLAN_FORMAT = "hlr-lab.plan"
# bounds far beyond any rig, so that a typo (1e300) is refused here rather than overflowing in the geometry
Metres = Annotated[float, Field(ge=-1e3, le=1e3)]
Degrees = Annotated[float, Field(ge=-3600, le=3600)]
Vec3 = Annotated[list[Metres], Field(min_length=3, max_length=3)]
Matrix4 = Annotated[
    list[Annotated[list[Annotated[float, Field(ge=-1e6, le=1e6)]], Field(min_length=4, max_length=4)]],
    Field(min_length=4, max_length=4),
]


class PlacementRecord(OpenModel):
    """How the object's ``mesh_to_turntable`` was found (docs/formats.md, docs/placement.md): ``measured``
    by ``hlr-lab register`` from the photographs in ``photographs``, ``ambiguous`` (measured, but a turn
    about the axis is not determined: ``why``), or ``assumed`` (where the plan put it). The measured
    numbers: the outline's residual (px RMS), the share of the outline found and the photographed outline's
    offset all round (px, positive outside the mesh's: fitted with the placement), the standard errors of the
    shift (mm) and of the rotation vector (degrees), and the offset from ``nominal_mesh_to_turntable`` (the
    placement the plan assumed): the shift (mm), the rotation vector (degrees), its turn about the vertical
    and its tilt (degrees)."""

    status: Literal["measured", "ambiguous", "assumed"]
    method: str  # "outlines", "outlines+colours" (the colours fixed the turn), or "assumed"
    date: str  # ISO 8601, UTC
    nominal_mesh_to_turntable: Matrix4
    photographs: str | None = None
    residual_px: Annotated[float, Field(ge=0)] | None = None
    outline_seen: Annotated[float, Field(ge=0, le=1)] | None = None
    outline_offset_px: float | None = None  # the photographed outline outside (+) the mesh's, all round
    se_shift_mm: Vec3 | None = None
    se_rotation_deg: Vec3 | None = None
    offset_shift_mm: Vec3 | None = None
    offset_rotation_deg: Vec3 | None = None
    offset_turn_deg: Degrees | None = None
    offset_tilt_deg: Degrees | None = None
    why: str | None = None


class PlanObject(OpenModel):
    """The object planned for: its mesh (relative to the plan or ``builtin:…``) and checksum, its regions,
    how it lies on the plate (``mesh_to_turntable``, 4×4; ``up`` and ``scale`` as given to plan) and, when
    that was measured (``hlr-lab register``), how (``placement``)."""

    mesh: str
    sha256: str
    regions: list[RegionEntry]
    texture: str | None = None
    texture_sha256: str | None = None  # of the texture's pixels (object.mesh.texture_sha256)
    mesh_to_turntable: Matrix4 | None = None
    up: str = "z"
    scale: float = 1.0
    placement: PlacementRecord | None = None

    @field_validator("mesh_to_turntable")
    @classmethod
    def _a_placement(cls, m: list[list[float]] | None) -> list[list[float]] | None:
        """A rigid motion with a scale: last row (0, 0, 0, 1), its 3×3 part invertible (a singular one
        flattens the mesh) and not a mirror image (the mesh's outside would face in)."""
        if m is None:
            return m
        a = np.asarray(m, float)
        if not np.allclose(a[3], [0, 0, 0, 1]):
            raise ValueError("the last row of a placement is 0, 0, 0, 1")
        singular = np.linalg.svd(a[:3, :3], compute_uv=False)
        if singular[-1] <= 1e-9 * singular[0]:
            raise ValueError("the placement is singular (it flattens the mesh): re-plan the object")
        if np.linalg.det(a[:3, :3]) < 0:
            raise ValueError("the placement mirrors the mesh (a negative determinant): re-plan the object")
        return m


class PlanParameters(OpenModel):
    """What the plan was made with: θc (degrees), M samples per region (in ``count`` units), the light
    sphere's radius (m) and where it came from, the criterion; hlr-lab's own settings for the record."""

    theta_c_deg: float = Field(gt=0, lt=90)
    min_samples: float = Field(gt=0)
    sphere_radius_m: float = Field(gt=0)
    count: Literal["pixels", "vertices"]
    criterion: Literal["capped", "plain"] = "capped"
    min_diffuse: float | None = Field(default=None, ge=0)  # diffuse-only samples each region needs
    # each region's own θc where it was measured (an adaptive run's re-plan), by region id; the others
    # theta_c_deg
    region_theta_c_deg: dict[str, Annotated[float, Field(gt=0, lt=90)]] | None = None
    # each region's own M and diffuse-only need where the precision asked of it set them (an adaptive
    # run's re-plan), by region id; the others min_samples, min_diffuse
    region_min_samples: dict[str, Annotated[float, Field(gt=0)]] | None = None
    region_min_diffuse: dict[str, Annotated[float, Field(ge=0)]] | None = None
    sphere_source: SphereSource = "rig"  # "scale": an analysis plan (--sphere-scale), for no rig
    # what hlr-lab's planner was run with, for the record (another tool's plan may leave them out)
    sphere_centre_m: Vec3 | None = None
    cone: str | None = None
    candidate_spacing_deg: float | None = None
    max_view_angle_deg: float | None = None
    shadows: bool | None = None
    views_deg: list[float] | None = None
    max_lights: int | None = None


class PlanLight(OpenModel):
    """A light position: gantry angles (degrees), the world position (m) and the same in the mesh's frame."""

    azimuth_deg: Degrees
    elevation_deg: Degrees
    position_m: Vec3
    position_mesh_m: Vec3


POSE_ID = r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$"  # a pose id names its frames' files: nothing else gets in
RESERVED_POSE_IDS = {"lamp-reference"}  # the lamp watch's frames (hlr_lab.acquisition.poses)


class PlanPose(OpenModel):
    """One pose ``acquire`` takes: the turntable angle (degrees), the light, the exposures (seconds) and
    the samples each region is expected to get from it."""

    id: str
    turntable_deg: Degrees
    light: PlanLight
    camera_position_mesh_m: Vec3
    exposures_s: Annotated[
        list[Annotated[float, Field(gt=0, le=3600)]], Field(min_length=1)
    ]  # an hour at most
    expected: dict[str, float]
    greedy_step: int | None = None  # the order hlr-lab's greedy chose the light in
    expected_diffuse: dict[str, float] | None = None  # diffuse-only samples per region (Rd)
    # "diffuse": added for diffuse-only samples; "taken": photographed before the plan was made (an adaptive
    # run's pilot), counted, not chosen
    purpose: Literal["highlights", "diffuse", "taken"] | None = None


class RegionCoverage(OpenModel):
    """A region's planned samples over all poses, and whether they reach M."""

    samples: float = Field(ge=0)
    satisfied: bool
    needed: float | None = None
    diffuse_samples: float | None = Field(default=None, ge=0)
    diffuse_needed: float | None = None


class PlanSummary(OpenModel):
    """What hlr-lab's planner reports about its plan, for people: every field optional (another tool's plan)."""

    lights: int | None = None
    lights_by_criterion: dict[str, int] | None = None  # each greedy's own count, before the fewest was kept
    lower_bound: int | None = None  # no set of the candidates satisfies the same regions with fewer lights
    lp_bound: float | None = None  # the set multicover's LP relaxation (fractional lights)
    optimum_proven: bool | None = None  # the plan has the fewest lights (on the planner's estimated counts)
    chosen_by: str | None = None  # "greedy (capped)", "greedy (plain)" or "integer programme"
    optimum_status: str | None = None  # how the integer programme ended
    views_used: list[float] | None = None
    candidates: int | None = None
    reachable_candidates: int | None = None
    rig: str | None = None
    seconds: dict[str, float] | None = None
    created: str | None = None  # ISO 8601, UTC
    software: str | None = None


class Uncovered(OpenModel):
    """A region no pose covers, and why (not visible, highlight unreachable, …)."""

    region: int
    reason: str


class PlanFile(OpenModel):
    """``plan.json`` (docs/formats.md): the object, the planner's parameters, the poses ``acquire`` runs
    (turntable angle, light on the gantry sphere, exposures) and the coverage they give each region. Keys
    another tool adds are kept."""

    format: Literal["hlr-lab.plan"]
    version: Literal[1]
    object: PlanObject
    parameters: PlanParameters
    poses: list[PlanPose]
    coverage: dict[str, RegionCoverage]
    uncovered: list[Uncovered] = []
    summary: PlanSummary | None = None

    @field_validator("poses")
    @classmethod
    def _ids_unique_and_free(cls, poses: list[PlanPose]) -> list[PlanPose]:
        seen: dict[str, int] = {}
        for i, pose in enumerate(poses):
            if not re.fullmatch(POSE_ID, pose.id):
                raise ValueError(
                    f"poses[{i}].id {pose.id!r}: a pose id is 1–64 letters, digits, _ and - (it names the frames' "
                    "files); rename it"
                )
            if pose.id in RESERVED_POSE_IDS:
                raise ValueError(
                    f"poses[{i}].id {pose.id!r} is reserved (the lamp's reference frames); rename it"
                )
            if pose.id in seen:
                raise ValueError(
                    f"poses[{i}].id {pose.id!r} is also poses[{seen[pose.id]}]'s: pose ids must be unique"
                )
            seen[pose.id] = i
        return poses


def build_plan(
    result: PlanResult,
    seg: Segmentation,
    *,
    mesh_ref: str,
    sha256: str,
    texture_ref: str | None,
    texture_sha256: str | None,
    mesh_to_turntable: np.ndarray,
    up: str,
    scale: float,
    exposures_s: tuple[float, ...],
    rig_name: str,
) -> PlanFile:
    """``plan.json`` for the planner's ``result`` on the segmented mesh.

    Parameters
    ----------
    mesh_ref, texture_ref
        The mesh (and texture) as the plan names them: relative to the plan's folder, or ``builtin:…``.
    sha256, texture_sha256
        The mesh file's checksum and its texture's (:func:`hlr_lab.object.mesh.texture_sha256`), checked
        wherever the plan's mesh is loaded.
    mesh_to_turntable
        (4, 4) placement of the mesh on the plate: its frame and units (``scale``, ``up``) → metres.
    exposures_s
        Each pose's exposures, seconds.
    rig_name
        The rig planned for, for the summary.
    """
    mesh_from_tt = np.linalg.inv(mesh_to_turntable)
    s = result.settings
    needed, diffuse_needed = s.needed(seg.n_regions), s.diffuse_needed(seg.n_regions)

    def to_mesh(p: np.ndarray) -> list[float]:
        return _r(mesh_from_tt[:3, :3] @ p + mesh_from_tt[:3, 3])

    poses = [
        PlanPose(
            id=f"p{i:03d}",
            turntable_deg=round(light.turntable_deg, 6),
            light=PlanLight(
                azimuth_deg=round(light.azimuth_deg, 4),
                elevation_deg=round(light.elevation_deg, 4),
                position_m=_r(light.light_world),
                position_mesh_m=to_mesh(light.light_turntable),
            ),
            camera_position_mesh_m=to_mesh(light.camera_turntable),
            exposures_s=list(exposures_s),
            expected={str(r): round(float(c), 1) for r, c in enumerate(light.expected) if c > 0},
            greedy_step=light.step,
            expected_diffuse={str(r): round(float(c), 1) for r, c in enumerate(light.diffuse) if c > 0},
            purpose=light.purpose,
        )
        for i, light in enumerate(result.lights)
    ]
    return PlanFile(
        format=PLAN_FORMAT,
        version=1,
        object=PlanObject(
            mesh=mesh_ref,
            sha256=sha256,
            texture=texture_ref,
            texture_sha256=texture_sha256,
            regions=[RegionEntry.of(r) for r in seg.regions],
            mesh_to_turntable=[_r(row, 9) for row in mesh_to_turntable],
            up=up,
            scale=scale,
        ),
        parameters=PlanParameters(
            theta_c_deg=s.theta_c_deg,
            min_samples=s.min_samples,
            sphere_radius_m=round(result.sphere.radius, 6),
            count=s.count,
            criterion=s.criterion,
            min_diffuse=s.min_diffuse,
            region_theta_c_deg=_by_region(s.region_theta_c_deg, 3),
            region_min_samples=_by_region(s.region_min_samples, 3),
            region_min_diffuse=_by_region(s.region_min_diffuse, 3),
            sphere_centre_m=_r(result.sphere.centre),
            sphere_source=result.sphere.source,
            cone="half-angle theta_c about the mirror direction",
            candidate_spacing_deg=s.spacing_deg,
            max_view_angle_deg=s.max_view_angle_deg,
            shadows=s.shadows,
            views_deg=[float(v) for v in result.views_considered],
            max_lights=s.max_lights,
        ),
        poses=poses,
        coverage={
            str(r): RegionCoverage(
                samples=round(float(result.coverage[r]), 1),
                satisfied=bool(result.satisfied[r]),
                needed=float(needed[r]),
                diffuse_samples=round(float(result.diffuse[r]), 1),
                diffuse_needed=float(diffuse_needed[r]),
            )
            for r in range(seg.n_regions)
        },
        uncovered=[Uncovered(region=r, reason=why) for r, why in sorted(result.uncovered.items())],
        summary=PlanSummary(
            lights=len(result.lights),
            lights_by_criterion=result.lights_by_criterion,
            lower_bound=result.optimum.lower_bound,
            lp_bound=round(result.optimum.lp_value, 4),
            optimum_proven=result.optimum.proven,
            chosen_by=result.optimum.chosen_by,
            optimum_status=result.optimum.status,
            views_used=sorted({p.turntable_deg for p in poses}),
            candidates=result.candidates,
            reachable_candidates=result.reachable,
            rig=rig_name,
            seconds={k: round(v, 3) for k, v in result.seconds.items()},
            created=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            software=f"hlr-lab {__version__}",
        ),
    )


def write_plan(path: str | Path, plan: PlanFile) -> None:
    """Write ``plan`` to ``path`` in one piece (a crash leaves the old file or the new one)."""
    write_json(path, plan)


def read_plan(path: str | Path) -> PlanFile:
    """Read and validate a plan; an unknown format or version, or a malformed field, is one InputError."""
    path = Path(path)
    return read_format(path, PLAN_FORMAT, PlanFile)


def _by_region(values: tuple[float, ...] | None, digits: int) -> dict[str, float] | None:
    """A per-region setting (the segmentation's order) by region id, as a plan records it."""
    return None if values is None else {str(r): round(v, digits) for r, v in enumerate(values)}


def _r(v, digits: int = 6) -> list[float]:
    return [round(float(x), digits) for x in v]
