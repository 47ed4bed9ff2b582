"""``hlr-lab bench register``: how well the object's placement is measured from its outlines (issue 22).

Each case puts an object of the bench (the built-in pebble, the painted bunny, Spot) somewhere the plan
does not expect — turned about the axis, off it by up to 2 cm, tilted — renders the registration views of
that world (six turntable angles, the lamps of :func:`hlr_lab.placement.photographs.registration_lamps`, each
exposed by the sensor model), measures the placement from them alone and compares it with the truth:
every mesh vertex's distance from where it really lies (RMS and worst, mm) and the rotation's error.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from benchmarks.materials import BENCH_OBJECTS, bench_mesh
from hlr_lab.errors import PlacementError
from hlr_lab.formats.plan import read_plan, write_plan
from hlr_lab.formats.planned_object import load_planned_mesh, mesh_to_turntable
from hlr_lab.instrument.motion import estimate_duration_s, motion_targets
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.raycast import PixelSurface
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import acquire_plan, fit_into, plan_object
from hlr_lab.placement.faces import other_rests, register_on_faces
from hlr_lab.placement.photographs import ObservedView, observe, registration_lamps
from hlr_lab.placement.pose import PlacementFrame, local_difference, rotation_error_deg, vertex_errors_mm
from hlr_lab.placement.solve import Outlines, Registration, register, turn_by_colours
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.planner import PlanSettings
from hlr_lab.registration import register_plan
from hlr_lab.registration.capture import REGISTRATION_PLAN
from hlr_lab.rig.file import Rig
from sim.render.scene import Material, SceneSpec
from worlds.placement_views import photograph_views
from worlds.plan_world import sim_scene

VIEWS_DEG = (0.0, 60.0, 120.0, 180.0, 240.0, 300.0)


@dataclass(frozen=True)
class Placed:
    """Where a case's object really lies, from the plan's placement: a tilt about the turntable's x axis,
    then a turn about the vertical (both through the object's centre, degrees), then a shift on the plate
    (mm)."""

    dx_mm: float
    dy_mm: float
    yaw_deg: float
    tilt_deg: float = 0.0

    def params(self) -> np.ndarray:
        """(6,) as :class:`PlacementFrame` takes them."""
        turn = Rotation.from_euler("xz", [self.tilt_deg, self.yaw_deg], degrees=True)
        return np.concatenate([np.degrees(turn.as_rotvec()), [self.dx_mm, self.dy_mm, 0.0]])

    def label(self) -> str:
        tilt = f", tilt {self.tilt_deg:g}°" if self.tilt_deg else ""
        return f"yaw {self.yaw_deg:g}°, ({self.dx_mm:g}, {self.dy_mm:g}) mm{tilt}"


PLACEMENTS = (Placed(4, -3, 37), Placed(12, -8, 200), Placed(-20, 0, -95), Placed(6, 9, 130, tilt_deg=3))


def random_placements(count: int, seed: int) -> tuple[Placed, ...]:
    """``count`` seeded placements: turned anywhere about the axis, up to 15 mm off it along each plate axis,
    tilted up to 3° — for the standard errors' coverage (:func:`coverage_lines`)."""
    rng = np.random.default_rng(seed)
    return tuple(
        Placed(
            float(rng.uniform(-15, 15)),
            float(rng.uniform(-15, 15)),
            float(rng.uniform(-180, 180)),
            float(rng.uniform(0, 3)),
        )
        for _ in range(count)
    )


@dataclass(frozen=True)
class RegisterFigures:
    """One case: the object, where it lay, the errors of the measured placement, and the times (s); ``error``
    (6,): the measured placement less the true one in the local coordinates of its standard errors (turns
    about the turntable's axes in degrees, shifts in mm: :func:`hlr_lab.placement.pose.local_difference`)."""

    object: str
    placed: Placed
    rms_mm: float
    worst_mm: float
    rotation_deg: float
    registration: Registration
    render_s: float
    solve_s: float
    error: np.ndarray = field(default_factory=lambda: np.zeros(6))


def register_case(
    name: str, plan_path: Path, rig: Rig, placed: Placed, *, spp: int, seed: int
) -> RegisterFigures:
    """Render ``plan_path``'s object lying as ``placed`` says on the simulated ``rig`` and measure it."""
    plan = read_plan(plan_path)
    mesh = load_planned_mesh(plan, plan_path)
    nominal = mesh_to_turntable(plan)
    frame = PlacementFrame.about(mesh.vertices, nominal)
    true = frame.matrix(placed.params())
    world = replace(sim_scene(plan, plan_path, None), mesh_to_turntable=true)
    views, render_s = _photographed(world, rig, spp=spp, seed=seed)
    started = time.perf_counter()
    found = register(Outlines(mesh, rig.camera, frame, views))
    solved = time.perf_counter()
    errors = vertex_errors_mm(mesh.vertices, found.mesh_to_turntable, true)
    return RegisterFigures(
        object=name,
        placed=placed,
        rms_mm=float(np.sqrt(np.mean(errors**2))),
        worst_mm=float(errors.max()),
        rotation_deg=rotation_error_deg(found.mesh_to_turntable, true),
        registration=found,
        render_s=render_s,
        solve_s=solved - started,
        error=local_difference(found.params, placed.params()),
    )


def _photographed(world: SceneSpec, rig: Rig, *, spp: int, seed: int) -> tuple[list[ObservedView], float]:
    """The registration views of ``world`` (:data:`VIEWS_DEG`, the registration lamps) as the photographs
    give them, and the seconds the simulator took to render and expose them."""
    started = time.perf_counter()
    k = rig.gantry.kinematics
    lamps = np.array([k.light_position(k.ticks_for(az, el)) for az, el in registration_lamps(rig)])
    frames, sensor = photograph_views(world, rig.camera, list(VIEWS_DEG), lamps, spp=spp, seed=seed)
    rendered = time.perf_counter() - started
    return [observe(v, sensor, where=f"the view at {v.turntable_deg:g}°") for v in frames], rendered


def register_bench(
    folder: Path,
    rig: Rig,
    *,
    objects: tuple[str, ...],
    assets: Path | None,
    spp: int = 16,
    seed: int = 0,
    placements: tuple[Placed, ...] = PLACEMENTS,
    progress: Callable[[str], None] = lambda _: None,
    done: Callable[[RegisterFigures], None] = lambda _: None,
) -> list[RegisterFigures]:
    """Every object of ``objects`` planned into ``folder`` (new or empty) and measured in every one of
    ``placements``."""
    results = []
    for name in objects:
        progress(f"planning {name}…")
        obj = BENCH_OBJECTS[name]
        mesh, spec = bench_mesh(name, assets, folder, seed=seed)
        plan, _ = plan_object(mesh, segment(mesh), rig, PlanSettings(), mesh_spec=spec, plan_folder=folder,
                              up=obj.up, scale=obj.scale)  # fmt: skip
        plan_path = folder / f"{name}-plan.json"
        write_plan(plan_path, plan)
        for placed in placements:
            progress(f"{name}: {placed.label()}…")
            result = register_case(name, plan_path, rig, placed, spp=spp, seed=seed)
            done(result)
            results.append(result)
    return results


ON_ITS_SIDE = Placed(5, -4, 60)  # the object on its likeliest other face, then turned 60° and 5, −4 mm off


@dataclass(frozen=True)
class FaceFigures:
    """An object resting on another face than the plan's: the stable pose it lies on (rank), the one the
    measurement found (None: refused, with ``refusal``), every vertex's error (mm) and the rotation's, the
    solve's time (s: the plan's face refused, then the other faces searched)."""

    object: str
    true_rank: int
    found_rank: int | None
    rms_mm: float
    rotation_deg: float
    solve_s: float
    refusal: str | None = None


def face_case(
    name: str, plan_path: Path, rig: Rig, placed: Placed = ON_ITS_SIDE, *, spp: int, seed: int
) -> FaceFigures:
    """Render ``plan_path``'s object resting on the likeliest of the mesh's stable poses that is not the plan's
    (:func:`hlr_lab.placement.faces.other_rests`), placed from there as ``placed`` says, and measure it as
    ``hlr-lab register`` does (:func:`hlr_lab.placement.faces.register_on_faces`)."""
    plan = read_plan(plan_path)
    mesh = load_planned_mesh(plan, plan_path)
    nominal = mesh_to_turntable(plan)
    rank, resting, _ = next(other_rests(mesh, nominal, plan.object.scale))
    frame = PlacementFrame.about(mesh.vertices, resting)
    true = frame.matrix(placed.params())
    world = replace(sim_scene(plan, plan_path, None), mesh_to_turntable=true)
    views, _ = _photographed(world, rig, spp=spp, seed=seed)
    started = time.perf_counter()
    try:
        rest = register_on_faces(mesh, rig.camera, nominal, views, plan.object.scale)
    except PlacementError as exc:
        return FaceFigures(
            name, rank, None, float("nan"), float("nan"), time.perf_counter() - started, str(exc)
        )
    solved = time.perf_counter() - started
    errors = vertex_errors_mm(mesh.vertices, rest.found.mesh_to_turntable, true)
    return FaceFigures(name, rank, rest.pose_rank, float(np.sqrt(np.mean(errors**2))),
                       rotation_error_deg(rest.found.mesh_to_turntable, true), solved)  # fmt: skip


def face_bench(
    folder: Path,
    rig: Rig,
    *,
    objects: tuple[str, ...],
    spp: int = 16,
    seed: int = 0,
    done: Callable[[FaceFigures], None] = lambda _: None,
) -> list[FaceFigures]:
    """:func:`face_case` for each of ``objects``, on the plans :func:`register_bench` left in ``folder``."""
    results = []
    for name in objects:
        results.append(face_case(name, folder / f"{name}-plan.json", rig, spp=spp, seed=seed))
        done(results[-1])
    return results


def face_line(r: FaceFigures) -> str:
    if r.found_rank is None:
        return f"{r.object:7s} on stable pose {r.true_rank}: REFUSED ({r.refusal}); solve {r.solve_s:.0f} s"
    which = "found" if r.found_rank == r.true_rank else f"WRONG FACE (found {r.found_rank})"
    return (
        f"{r.object:7s} on stable pose {r.true_rank}, {ON_ITS_SIDE.label()}: {which}; vertices {r.rms_mm:.3f} mm "
        f"RMS, rotation {r.rotation_deg:.3f}°; solve {r.solve_s:.0f} s"
    )


CYLINDER_PLACEMENTS = (Placed(6, -3, 40), Placed(-10, 8, 200))


def cylinder_bench(
    rig: Rig, *, spp: int = 16, seed: int = 0, done: Callable[[CylinderFigures], None] = lambda _: None
) -> list[CylinderFigures]:
    """The painted cylinder in each of :data:`CYLINDER_PLACEMENTS`."""
    results = []
    for placed in CYLINDER_PLACEMENTS:
        results.append(cylinder_case(rig, placed, spp=spp, seed=seed))
        done(results[-1])
    return results


def case_line(r: RegisterFigures) -> str:
    g = r.registration
    ambiguous = f"; AMBIGUOUS: {g.ambiguous}" if g.ambiguous else ""
    return (
        f"{r.object:7s} {r.placed.label():34s} vertices {r.rms_mm:.3f} mm RMS, {r.worst_mm:.3f} worst; "
        f"rotation {r.rotation_deg:.3f}° (stated ± {float(np.linalg.norm(g.se[:3])):.3f}°); "
        f"outline {g.residual_px:.2f} px RMS, {g.outline_offset_px:+.2f} px outside, {100 * g.outline_seen:.1f} % "
        "seen; "
        f"render {r.render_s:.1f} s, solve {r.solve_s:.1f} s{ambiguous}"
    )


COVERED = ("turn x", "turn y", "turn z", "shift x", "shift y", "shift z")


def coverage_lines(results: list[RegisterFigures]) -> list[str]:
    """Per object and over all, for each of the six numbers (:data:`COVERED`), the share of the cases whose
    error lies within 1 and 2 stated standard errors (a normal error: 68 % and 95 %)."""
    lines = ["", "errors within 1 / 2 stated standard errors (normal: 68 / 95 %):",
             "  " + " " * 9 + "".join(f"{n:>13s}" for n in COVERED) + f"{'all':>13s}"]  # fmt: skip
    groups = {
        name: [r for r in results if r.object == name] for name in dict.fromkeys(r.object for r in results)
    }
    if len(groups) > 1:
        groups["all"] = list(results)
    for name, mine in groups.items():
        z = np.abs(np.array([r.error / r.registration.se for r in mine]))  # (cases, 6)
        cells = [f"{100 * (c < 1).mean():5.0f} /{100 * (c < 2).mean():4.0f} %" for c in [*z.T, z.ravel()]]
        lines.append(f"  {name:7s} {len(mine):2d}" + "".join(f"{c:>13s}" for c in cells))
    return lines


def summary_lines(results: list[RegisterFigures]) -> list[str]:
    """The worst case per object, against the targets (0.3 mm RMS, 0.6 mm worst, 0.15°)."""
    lines = ["", "worst over the placements (targets: 0.3 mm RMS, 0.6 mm worst, 0.15°):"]
    for name in dict.fromkeys(r.object for r in results):
        mine = [r for r in results if r.object == name]
        lines.append(
            f"  {name:7s} {max(r.rms_mm for r in mine):.3f} mm RMS, {max(r.worst_mm for r in mine):.3f} mm worst, "
            f"{max(r.rotation_deg for r in mine):.3f}°; solve ≤ {max(r.solve_s for r in mine):.1f} s"
        )
    return lines


# the paper's own kind of object, painted: four sectors and the caps (its outline has no turn in it)
CYLINDER_RD = ((0.6, 0.2, 0.1), (0.15, 0.5, 0.2), (0.1, 0.2, 0.6), (0.5, 0.45, 0.1), (0.7, 0.7, 0.7))


@dataclass(frozen=True)
class CylinderFigures:
    """The painted cylinder: whether its outline was said ambiguous, the colour step's yaw error and stated
    error (degrees), every vertex's error after it (mm)."""

    placed: Placed
    outline_ambiguous: bool
    yaw_error_deg: float
    stated_deg: float
    rms_mm: float
    solve_s: float


def painted_cylinder() -> tuple[ColouredMesh, np.ndarray]:
    """A cylinder (r 3 cm, h 5 cm) and its faces' regions (F,): four 90° sectors of the side, then the caps.
    The caps have vertices of their own, as a real can's sharp rim: shared ones would smooth the shading
    normals across the rim and leave the far part of the top unlit under any lamp."""
    can = trimesh.creation.cylinder(radius=0.03, height=0.05, sections=128)
    cap = np.abs(np.asarray(can.face_normals)[:, 2]) > 0.99
    vertices, faces = [], []
    for part in (np.asarray(can.faces)[~cap], np.asarray(can.faces)[cap]):
        used, local = np.unique(part, return_inverse=True)
        faces.append(local.reshape(-1, 3) + sum(len(v) for v in vertices))
        vertices.append(np.asarray(can.vertices)[used])
    mesh = ColouredMesh(np.concatenate(vertices), np.concatenate(faces).astype(np.int64))
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    sector = (np.degrees(np.arctan2(centroids[:, 1], centroids[:, 0])) % 360 // 90).astype(np.int64)
    return mesh, np.where(np.abs(mesh.face_normals[:, 2]) > 0.99, 4, sector)


def cylinder_case(rig: Rig, placed: Placed, *, spp: int, seed: int) -> CylinderFigures:
    """Render the painted cylinder lying as ``placed`` says and measure its placement: the outlines, then
    the colours (the regions' expected chromaticity: their Rd's)."""
    mesh, face_region = painted_cylinder()
    nominal = placement(mesh)
    frame = PlacementFrame.about(mesh.vertices, nominal)
    true = frame.matrix(placed.params())
    materials = [Material(rd, (0.05, 0.05, 0.05), 40.0) for rd in CYLINDER_RD]
    world = SceneSpec(mesh.vertices, mesh.faces, face_region, materials, true)
    views, _ = _photographed(world, rig, spp=spp, seed=seed)
    started = time.perf_counter()
    outlines = Outlines(mesh, rig.camera, frame, views)
    found = register(outlines)
    rd = np.array(CYLINDER_RD)
    expected = rd[:, :2] / rd.sum(axis=1, keepdims=True)

    def regions(surface: PixelSurface) -> np.ndarray:
        return np.where(surface.hit, face_region[np.maximum(surface.face, 0)], -1)

    turned = turn_by_colours(outlines, found, regions, expected)
    solved = time.perf_counter()
    errors = vertex_errors_mm(mesh.vertices, turned.mesh_to_turntable, true)
    return CylinderFigures(
        placed=placed,
        outline_ambiguous=found.ambiguous is not None,
        yaw_error_deg=rotation_error_deg(turned.mesh_to_turntable, true),
        stated_deg=float(turned.se[2]),
        rms_mm=float(np.sqrt(np.mean(errors**2))),
        solve_s=solved - started,
    )


def cylinder_line(r: CylinderFigures) -> str:
    said = "ambiguous, as it should be" if r.outline_ambiguous else "NOT said ambiguous"
    return (
        f"cylinder {r.placed.label():33s} outline: {said}; colours: rotation {r.yaw_error_deg:.3f}° "
        f"(stated ± {r.stated_deg:.3f}°), vertices {r.rms_mm:.3f} mm RMS; solve {r.solve_s:.1f} s"
    )


END_TO_END = Placed(12, -8, 200)  # off the axis and turned: no tilt (the world's --object-offset has none)


@dataclass(frozen=True)
class EndToEndFigures:
    """``hlr-lab register`` run on the simulated rig with the object moved, then the placed plan acquired and
    fitted there, beside the plan acquired unregistered: the worst region's errors (per cent) of each, and
    the registration's rig time (estimated, s) and wall time (s, the simulator rendering the frames)."""

    object: str
    placed: Placed
    registered: dict[str, float]
    unregistered: dict[str, float]
    rig_s: float
    wall_s: float
    flagged_registered: int
    flagged_unregistered: int


def end_to_end_case(
    name: str, plan_path: Path, rig: Rig, folder: Path, placed: Placed = END_TO_END
) -> EndToEndFigures:
    """Register ``plan_path``'s object lying as ``placed`` says (through the real drivers on the simulated
    rig), acquire and fit the placed plan, and the plan as it was, in the same world; compare with the truth."""
    from worlds.plan_world import ObjectOffset, sim_links
    from worlds.truth import worst_errors_pct

    plan = read_plan(plan_path)
    offset = ObjectOffset(placed.dx_mm / 1000, placed.dy_mm / 1000, placed.yaw_deg)
    with contextlib.ExitStack() as stack:
        links = sim_links(stack, rig, plan, plan_path, None, None, 20.0, offset)
        started = time.perf_counter()
        done = register_plan(
            plan_path, rig, folder / f"{name}-photographs", folder / f"{name}-placed.json", links=links
        )
        wall = time.perf_counter() - started
        figures = {}
        for label, path in (("registered", done.output), ("unregistered", plan_path)):
            session = folder / f"{name}-{label}"
            acquire_plan(path, rig, session, links=links)
            fit = fit_into(session, systematic=False)
            figures[label] = (worst_errors_pct(read_plan(path), path, None, session),
                              len(fit.diagnostics["alignment"]["flagged"]))  # fmt: skip
    registration = read_plan(done.folder / REGISTRATION_PLAN)
    rig_s = estimate_duration_s(registration, motion_targets(registration, rig), rig)
    return EndToEndFigures(name, placed, figures["registered"][0], figures["unregistered"][0], rig_s, wall,
                           figures["registered"][1], figures["unregistered"][1])  # fmt: skip


def end_to_end_line(r: EndToEndFigures) -> str:
    def worst(e: dict[str, float]) -> str:
        return f"Rd {e['rd']:.2f} %, Rs {e['rs']:.2f} %, n {e['n']:.2f} %"

    return (
        f"{r.object:7s} {r.placed.label():22s} registered: {worst(r.registered)} ({r.flagged_registered} poses "
        f"flagged); unregistered: {worst(r.unregistered)} ({r.flagged_unregistered} flagged); registration "
        f"{r.rig_s:.0f} s of rig time, {r.wall_s:.0f} s wall"
    )


def end_to_end_bench(
    folder: Path,
    rig: Rig,
    *,
    objects: tuple[str, ...],
    done: Callable[[EndToEndFigures], None] = lambda _: None,
) -> list[EndToEndFigures]:
    """:func:`end_to_end_case` for each of ``objects``, on the plans :func:`register_bench` left in ``folder``."""
    results = []
    for name in objects:
        results.append(end_to_end_case(name, folder / f"{name}-plan.json", rig, folder))
        done(results[-1])
    return results
