"""The measurement's steps as functions: load an object, plan it, acquire a plan, fit a session, report
it, export its materials. ``hlr-lab segment|plan|acquire|fit|report|export``, ``hlr-lab demo``, the
benchmarks and the tests all call these; the commands only parse options and print.

Each step reads and writes files (plan.json, a session folder: docs/sessions.md, materials.json), so
any step can be run again alone. Opening the rig (devices, camera, the safe state on every exit) is
:func:`hlr_lab.instrument.control.open_rig`, which :func:`acquire_plan` uses through
:func:`hlr_lab.acquisition.run.acquire_session`. The layers: docs/architecture.md.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from hlr_lab.acquisition.poses import Bracketing, Outcome, Step
from hlr_lab.acquisition.run import PLANNED_ONLY, acquire_session
from hlr_lab.acquisition.white_reference import reference_meter
from hlr_lab.errors import InputError
from hlr_lab.files import LINK_REFUSED, atomic_write_all, model_json
from hlr_lab.fitting import DEFAULT_ESTIMATOR, EstimatorName
from hlr_lab.formats.materials import MATERIALS_FORMAT, read_materials
from hlr_lab.formats.plan import PlacementRecord, PlanFile, build_plan, read_plan
from hlr_lab.formats.planned_object import load_planned_mesh, mesh_to_turntable, planned_segmentation
from hlr_lab.formats.regions import mesh_reference, read_regions
from hlr_lab.geometry.silhouette import object_window
from hlr_lab.instrument.control import NO_OVERRIDES
from hlr_lab.instrument.devices import Links
from hlr_lab.instrument.motion import motion_targets
from hlr_lab.object.mesh import ColouredMesh, load_mesh, texture_sha256
from hlr_lab.object.procedural import BUILTIN_PREFIX, builtin_object
from hlr_lab.object.segment import Segmentation, segment
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.planner import PlanResult, PlanSettings, TakenLight, plan_lights
from hlr_lab.reflectance.radiance_file import RadianceHeader, write_radiance
from hlr_lab.reflectance.session_fit import (
    DIAGNOSTICS,
    DIAGNOSTICS_FORMAT,
    MATERIALS,
    RADIANCE,
    FitResult,
    FitStep,
    PoseRadiance,
    Session,
    fit_session,
    open_session,
)
from hlr_lab.rig.file import Rig
from hlr_lab.session.folder import check_new_session, check_session_folder
from hlr_lab.session.journal import JOURNAL, read_journal
from hlr_lab.session.lamp import LampWatch, lamp_watch_for
from hlr_lab.session.outputs import check_outputs, mesh_files
from hlr_lab.session.stages import stage_lines

if TYPE_CHECKING:
    from hlr_lab.report.build import ReportFigures

REPORT = "report.html"  # report's default output, in the session
EXPORT_FORMATS = {"obj": ".obj", "gltf": ".glb", "mitsuba": ""}  # format → the file's suffix ("": a folder)


def load_object(spec: str, texture: Path | None = None) -> ColouredMesh:
    """The object to measure: a mesh file with colours (or ``texture``), or ``builtin:NAME``."""
    if spec.startswith(BUILTIN_PREFIX):
        if texture is not None:
            raise InputError("--texture cannot be used with a built-in object", field="--texture")
        return builtin_object(spec).mesh
    return load_mesh(spec, texture, need_colour=True)


def plan_object(
    mesh: ColouredMesh,
    segmentation: Segmentation,
    rig: Rig,
    settings: PlanSettings,
    *,
    mesh_spec: str,
    plan_folder: Path,
    up: str = "z",
    scale: float = 1.0,
    to_turntable: np.ndarray | None = None,
    taken: Sequence[TakenLight] = (),
) -> tuple[PlanFile, PlanResult]:
    """Plan light positions for ``mesh`` (its ``segmentation``'s regions) on ``rig``: the plan file's
    contents (to write with :func:`hlr_lab.formats.plan.write_plan`; the mesh is referred to as
    ``mesh_spec``, relative to ``plan_folder`` where the plan will be) and the planner's full result.
    ``up``, ``scale``: how the mesh stands on the plate (its up axis; mesh units → metres), centred on the
    axis; ``to_turntable`` (4, 4) instead: where it was measured to lie (:func:`replan_placed`). ``taken``:
    lights already photographed, which the plan starts with (:func:`~hlr_lab.planning.planner.plan_lights`)."""
    if to_turntable is None:
        to_turntable = placement(mesh, up=up, scale=scale)
    result = plan_lights(mesh.transformed(to_turntable), segmentation, rig, settings, taken=taken)
    texture = None if mesh.texture_source is None else mesh_reference(mesh.texture_source, plan_folder)
    plan = build_plan(
        result,
        segmentation,
        mesh_ref=mesh_reference(mesh_spec, plan_folder),
        sha256=mesh.sha256 or "",
        texture_ref=texture,
        texture_sha256=texture_sha256(mesh),
        mesh_to_turntable=to_turntable,
        up=up,
        scale=scale,
        exposures_s=rig.exposure_bracket_s,
        rig_name=rig.name,
    )
    return plan, result


def plan_settings(plan: PlanFile) -> PlanSettings:
    """The settings ``plan`` was made with, as its parameters record them (another tool's plan: the
    defaults where it leaves one out)."""
    p, default = plan.parameters, PlanSettings()
    min_diffuse = default.min_diffuse if p.min_diffuse is None else p.min_diffuse
    return PlanSettings(
        theta_c_deg=p.theta_c_deg,
        min_samples=p.min_samples,
        count=p.count,
        views_deg=p.views_deg,
        spacing_deg=p.candidate_spacing_deg or default.spacing_deg,
        max_view_angle_deg=p.max_view_angle_deg or default.max_view_angle_deg,
        max_lights=p.max_lights or default.max_lights,
        shadows=default.shadows if p.shadows is None else p.shadows,
        criterion=p.criterion,
        min_diffuse=min_diffuse,
        region_theta_c_deg=_per_region(plan, p.region_theta_c_deg, p.theta_c_deg),
        region_min_samples=_per_region(plan, p.region_min_samples, p.min_samples),
        region_min_diffuse=_per_region(plan, p.region_min_diffuse, min_diffuse),
    )


def _per_region(plan: PlanFile, own: dict[str, float] | None, default: float) -> tuple[float, ...] | None:
    """A per-region setting the plan records by region id, in its regions' order (``default`` where it
    leaves a region out); None where it records none."""
    return None if own is None else tuple(own.get(str(r.id), default) for r in plan.object.regions)


def replan_placed(
    plan: PlanFile,
    plan_path: Path,
    mesh: ColouredMesh,
    rig: Rig,
    placed: PlacementRecord,
    to_turntable: np.ndarray,
    output: Path,
) -> tuple[PlanFile, PlanResult]:
    """``plan`` (read from ``plan_path``; ``mesh`` its mesh as :func:`load_planned_mesh` gives it) planned
    again, with its settings and regions, for the object lying as ``to_turntable`` (4, 4) says: where
    highlights fall depends on where the object lies. The plan to write at ``output`` (its mesh named
    relative to it), with ``placed`` as its placement record."""
    ref = plan.object.mesh
    spec = ref if ref.startswith(BUILTIN_PREFIX) else str(plan_path.parent / ref)
    replanned, result = plan_object(mesh, planned_segmentation(plan, mesh), rig, plan_settings(plan),
                                    mesh_spec=spec, plan_folder=output.parent, up=plan.object.up,
                                    scale=plan.object.scale, to_turntable=to_turntable)  # fmt: skip
    placed_object = replanned.object.model_copy(update={"placement": placed})
    return replanned.model_copy(update={"object": placed_object}), result


def acquire_plan(
    plan_path: Path,
    rig: Rig,
    session: Path,
    *,
    links: Links = NO_OVERRIDES,
    bracket: Bracketing = PLANNED_ONLY,
    force: bool = False,
    progress: Callable[[Step], None] = lambda _: None,
    on_start: Callable[[bool], None] = lambda _resumed: None,
    lamp: LampWatch | None = None,
    stage: tuple[PlanFile, Path] | None = None,
) -> Outcome:
    """Run the plan at ``plan_path`` on ``rig`` into ``session`` (created, or resumed): the motions are
    checked against the rig's limits before anything moves; adaptive bracketing watches the object's
    own pixels; ``lamp`` says how the lamp is watched (:mod:`hlr_lab.session.lamp`; None: as the rig's
    radiometric calibration says, :func:`~hlr_lab.session.lamp.lamp_watch_for`), and a white reference
    beside the object (the rig file's ``run_place_m``) measures it in every pose instead of a reference
    pose (:mod:`hlr_lab.acquisition.white_reference`). ``links`` replace the rig file's device addresses (the
    simulated rig's endpoints).

    ``stage``: an adaptive run's pilot or re-plan (:mod:`hlr_lab.adaptive`) and the path its object's files
    are named from, run instead of the plan's own poses (the session still records the plan at
    ``plan_path``). Without it, a session an adaptive run started is refused: its plan is in its journal.
    A folder that is not a session but holds other files is refused (a session is started in a new or
    empty folder: :func:`~hlr_lab.session.folder.check_new_session`)."""
    check_new_session(session)
    if stage is None:
        _refuse_adaptive_session(session)
    plan, poses_path = stage or (read_plan(plan_path), plan_path)
    targets = motion_targets(plan, rig, poses_path)
    if rig.file.lamp is None:
        raise InputError("acquisition switches the lamp: add a [lamp] section", path=rig.source, field="lamp")
    vertices = load_planned_mesh(plan, poses_path).transformed(mesh_to_turntable(plan)).vertices
    # where the object may appear at each turntable angle, computed once per angle
    windows = functools.cache(lambda turntable_deg: object_window(rig.camera, vertices, turntable_deg))
    reference = reference_meter(rig, vertices, windows)
    if lamp is None:
        lamp = lamp_watch_for(rig)[0]
    if reference is not None and lamp.every:
        raise InputError(
            "the rig file's white reference lies beside the object during runs: the lamp is measured on it in "
            "every pose; leave out --lamp-every (or remove run_place_m to use a reference pose instead)",
            path=rig.source,
            field="calibration.white_reference.run_place_m",
        )
    return acquire_session(plan, plan_path, targets, rig, session, links=links, bracket=bracket, force=force,
                           progress=progress, object_window=windows, on_start=on_start, lamp=lamp,
                           reference=reference)  # fmt: skip


def _refuse_adaptive_session(session: Path) -> None:
    """An adaptive run's session runs the plan its journal names, not the one given: refused by name."""
    check_session_folder(session)
    journal = session / JOURNAL
    if journal.is_file() and stage_lines(read_journal(journal)):
        raise InputError(
            "this session was started by an adaptive run (its pilot and re-plan are in its journal): continue "
            "it with acquire --adaptive, or give a new --out",
            path=session,
        )


def fit_into(
    session: Path,
    output: Path | None = None,
    *,
    theta_c_deg: float | Literal["auto"] = "auto",
    method: EstimatorName = DEFAULT_ESTIMATOR,
    allow_incomplete: bool = False,
    correct_lamp: bool = True,
    systematic: bool = True,
    progress: Callable[[FitStep], None] = lambda _: None,
    on_gaps: Callable[[list[str], int], None] = lambda _notes, _missing: None,
    radiance: bool = False,
) -> FitResult:
    """Fit ``session``'s frames and write materials.json (``output``, default SESSION/materials.json)
    with its diagnostics beside it; each pose's light scaled by the lamp's output the run measured
    (unless not ``correct_lamp``); the rig's own uncertainty propagated into ``*_sys`` unless not
    ``systematic``. ``radiance``: also each pose's merged radiance as ``radiance/POSE.exr`` beside the
    output (:mod:`hlr_lab.reflectance.radiance_file`), each written as its pose is done.
    ``on_gaps(notes, missing frames)`` hears what was left out before the fit starts. Refuses a session
    without frames, and an output over one of the session's files."""
    output = output or session / MATERIALS
    diagnostics = output.with_name(DIAGNOSTICS)
    s = open_session(session, allow_incomplete=allow_incomplete, correct_lamp=correct_lamp)
    exr = radiance_files(s, output.parent / RADIANCE) if radiance else {}
    check_outputs(
        [output, diagnostics, *exr.values()],
        writes=[MATERIALS_FORMAT, DIAGNOSTICS_FORMAT, *[None] * len(exr)],
    )
    on_gaps(s.gaps.notes(), len(s.gaps.missing_frames))
    if not s.views:
        raise InputError("the session has no frames yet; run hlr-lab acquire on it first", path=session)
    result = fit_session(s, theta_c_deg=theta_c_deg, method=method, systematic=systematic, progress=progress,
                         on_radiance=functools.partial(_write_radiance, s, exr) if exr else None)  # fmt: skip
    # both or neither: materials.json without its diagnostics would be a fit the report cannot show
    atomic_write_all([(output, model_json(result.materials).encode()),
                      (diagnostics, (json.dumps(result.diagnostics, indent=1) + "\n").encode())])  # fmt: skip
    return result


def radiance_files(session: Session, folder: Path) -> dict[str, Path]:
    """Pose id → the radiance file ``fit --radiance`` writes for it in ``folder``; InputError for a pose
    id that is not a plain file name, and for a ``folder`` that is a symbolic link or not a folder (a
    link would carry every file elsewhere)."""
    if folder.is_symlink():
        raise InputError(LINK_REFUSED, path=folder, field="--radiance")
    if folder.exists() and not folder.is_dir():
        raise InputError(
            "is not a folder: move it away for the radiance files", path=folder, field="--radiance"
        )
    files = {}
    for view in session.views:
        if Path(view.pose).name != view.pose or view.pose.startswith("."):
            raise InputError(f"pose {view.pose!r} cannot name a file: give the plan's poses plain ids",
                             path=session.plan_path, field="poses.id")  # fmt: skip
        files[view.pose] = folder / f"{view.pose}.exr"
    return files


def _write_radiance(session: Session, files: dict[str, Path], done: PoseRadiance) -> None:
    frames = [done.view.sidecars[e["file"]] for e in done.view.frames]
    camera, lamp = session.rig.camera, done.pose.light_world
    header = RadianceHeader(
        pose=done.view.pose,
        turntable_deg=float(done.pose.turntable_deg),
        lamp_m=(float(lamp[0]), float(lamp[1]), float(lamp[2])),
        lamp_power=float(done.pose.power),
        exposures_s=tuple(float(f["exposure_s"]) for f in frames),
        gains_db=tuple(float(f["gain_db"]) for f in frames),
        camera_matrix=tuple(tuple(float(x) for x in row) for row in camera.matrix),
        distortion=tuple(float(x) for x in np.ravel(camera.distortion)),
    )
    r = done.radiance
    write_radiance(files[done.view.pose], r.value, r.usable, done.used, header)


def report_into(
    session: Path, output: Path | None = None, *, progress: Callable[[str], None] = lambda _: None
) -> tuple[Path, ReportFigures, int]:
    """Write ``session``'s HTML report (``output``, default SESSION/report.html); returns its path, its
    figures (PSNR per pose) and its size in bytes."""
    from hlr_lab.report.build import build_report, write_report

    output = output or session / REPORT
    check_outputs([output], [session / MATERIALS, session / DIAGNOSTICS], writes=[None])
    s = open_session(session, allow_incomplete=True)  # fit said what is missing (so does materials.json)
    page, figures = build_report(s, progress=progress, page_folder=output.parent)
    write_report(output, page)
    return output, figures, output.stat().st_size


def export_materials(
    materials_path: Path,
    mesh: ColouredMesh,
    fmt: str,
    output: Path,
    *,
    regions_path: Path | None = None,
    mesh_spec: str = "the mesh",
) -> tuple[list[Path], list[int]]:
    """Write ``materials_path``'s materials on ``mesh`` as ``fmt`` (obj, gltf or mitsuba) to ``output``;
    the regions are ``regions_path``'s (default: the mesh segmented again). Every face is written: a
    region without a fitted material gets its colour as a named, diffuse-only stand-in. Returns the files
    written and the ids of the regions that got a stand-in."""
    from hlr_lab.export.gltf import write_gltf
    from hlr_lab.export.mitsuba import mitsuba_files, write_mitsuba
    from hlr_lab.export.obj import obj_files, write_obj
    from hlr_lab.export.regions import region_parts, stand_ins

    writers = {"obj": (obj_files, write_obj), "gltf": (lambda path, _parts: [path], write_gltf),
               "mitsuba": (mitsuba_files, write_mitsuba)}  # fmt: skip
    suffix = EXPORT_FORMATS[fmt]
    if suffix and output.suffix.lower() != suffix:
        raise InputError(
            f"--format {fmt} writes a {suffix} file: give a name ending in {suffix}", field="--output"
        )
    materials = read_materials(materials_path)
    if materials.sha256 and mesh.sha256 and materials.sha256 != mesh.sha256:
        raise InputError(
            f"made for another mesh ({materials.mesh}) than {mesh_spec}", path=materials_path, field="sha256"
        )
    seg = read_regions(regions_path, mesh) if regions_path else segment(mesh)
    parts = region_parts(mesh, seg, materials, source=str(materials_path))
    files, write = writers[fmt]
    written = files(output, parts)
    check_outputs(written, [materials_path, regions_path, *mesh_files(mesh)], writes=[None] * len(written))
    return write(output, parts), stand_ins(parts)
