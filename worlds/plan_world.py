"""The simulated world for a plan: the plan's object (or a scene file's) on the rig a rig file describes.

Without a scene file the world is the plan's own mesh, placed as the plan places it, with one default
material per planned region (the region's colour as Rd, a grey lobe; a textured mesh's faces each take
the region most of their texels show): enough to exercise the whole instrument; a scene file
(docs/formats.md, "Scene files") gives the true materials a fit is checked against.
"""

from __future__ import annotations

import contextlib
import tomllib
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

from hlr_lab.campaign.runner import AcquireJob, job_rig
from hlr_lab.errors import InputError
from hlr_lab.files import as_triple
from hlr_lab.formats.plan import PlanFile, read_plan
from hlr_lab.formats.planned_object import (
    face_regions,
    load_planned_mesh,
    mesh_to_turntable,
    nominal_placement,
    palette,
    region_ids,
    texel_regions,
)
from hlr_lab.geometry.colour import srgb8_to_linear
from hlr_lab.instrument.devices import Links
from hlr_lab.object.mesh import file_sha256
from hlr_lab.rig.file import SIM_RIG, Rig, load_rig
from sim.render.scene import Material, SceneError, SceneSpec, load_scene, pose_matrix

DEFAULT_RS, DEFAULT_N, RD_SCALE = (0.25, 0.25, 0.25), 40.0, 0.8  # Rd + Rs ≤ 1: energy is not created


@dataclass(frozen=True)
class ObjectOffset:
    """The world's object moved from where it would lie (a scene file's ``placed``, else the plan's
    placement): turned by ``yaw_deg`` about the turntable axis, then shifted by (``dx_m``, ``dy_m``) on the
    plate (turntable frame, metres). What a hand that places the object does; hlr-lab is not told."""

    dx_m: float = 0.0
    dy_m: float = 0.0
    yaw_deg: float = 0.0

    @classmethod
    def from_option(cls, value: tuple[float, float, float]) -> ObjectOffset:
        """From ``--object-offset DX_MM,DY_MM,YAW_DEG``."""
        dx_mm, dy_mm, yaw_deg = value
        return cls(dx_mm / 1000, dy_mm / 1000, yaw_deg)

    def moved(self, mesh_to_turntable: np.ndarray) -> np.ndarray:
        """(4, 4): ``mesh_to_turntable`` (4, 4) followed by this offset."""
        return pose_matrix((self.dx_m, self.dy_m, 0.0), (0.0, 0.0, self.yaw_deg)) @ mesh_to_turntable


def world_links(world) -> Links:
    """Where hlr-lab reaches a running :class:`sim.rig.SimRig`: its devices' endpoints, and its clock."""
    e = world.endpoints
    return Links(gantry=e.dynamixel, stage=e.modbus, camera=e.camera, clock=world.clock)


def sim_links(
    stack: contextlib.ExitStack,
    rig: Rig,
    plan: PlanFile,
    plan_path: Path,
    scene_path: Path | None,
    true_rig: str | Path | None,
    speed_factor: float,
    offset: ObjectOffset | None = None,
) -> Links:
    """Start the simulated world for ``plan`` (kept open by ``stack``) and return its endpoints: the
    scene file's world, or the plan's mesh with a default material per region (where :func:`sim_scene`
    puts it, moved by ``offset``); its rig as ``true_rig`` says, else as ``rig``."""
    from sim.rig import SimRig

    scene = sim_scene(plan, plan_path, scene_path, offset)
    world = stack.enter_context(
        SimRig(scene=scene, speed_factor=speed_factor, **world_geometry(rig, true_rig))
    )
    return world_links(world)


def job_links(job: AcquireJob, stack: contextlib.ExitStack) -> Links:
    """A campaign's acquire job's links: its rig file's own, or with ``sim`` a simulated world for it
    (kept open by ``stack`` for the job's attempts)."""
    if not job.sim:
        return Links()
    return sim_links(
        stack, job_rig(job), read_plan(job.plan), job.plan, job.scene, job.true_rig, job.speed_factor
    )


def world_geometry(rig: Rig, true_rig: str | Path | None = None, *, runs: bool = True) -> dict:
    """The simulated world's camera, gantry, turntable, servo ids, sensor and lamp, as :class:`sim.rig.SimRig` takes
    them: from ``true_rig`` (a rig file or ``builtin:NAME``: the world as it really is, while hlr-lab
    keeps believing ``rig``), else from ``rig``'s own file (the world is as hlr-lab believes). Either way
    the simulator reads the file itself (:mod:`sim.true_rig`). ``runs``: a world for runs, with the white
    reference beside the object when the file puts one there (not in front of calibration targets)."""
    from sim.true_rig import TrueRigError, load_true_rig

    if true_rig is not None and not str(true_rig).startswith("builtin:"):
        load_rig(true_rig)  # a rig file first: hlr-lab's checks name a wrong or misspelt field in one line
    try:
        if true_rig is not None:
            world = load_true_rig(true_rig)
        elif rig.source == "builtin:sim":
            with resources.as_file(resources.files("hlr_lab.data") / SIM_RIG) as path:
                world = load_true_rig(path)
        else:
            world = load_true_rig(rig.source)
    except TrueRigError as exc:
        raise InputError(str(exc), field="--true-rig" if true_rig is not None else "--rig") from exc
    return {
        "camera": world.camera,
        "gantry": world.gantry,
        "stage": world.stage,
        "servo_ids": world.servo_ids,
        "sensor": world.sensor,
        "lamp": world.lamp,
        "run_reference": world.run_reference if runs else None,
    }


def sim_scene(
    plan: PlanFile, plan_path: Path, scene_path: Path | None, offset: ObjectOffset | None = None
) -> SceneSpec:
    """The simulated world for ``plan``: the scene file's, or the plan's mesh with a default material per
    planned region. The object lies where the scene file's ``placed`` says, else where the plan assumed it
    before any registration (:func:`~hlr_lab.formats.planned_object.nominal_placement`: the plan is hlr-lab's
    belief, the scene the world's; a registered plan's measured placement is not the world's either), then
    moved by ``offset``."""
    scene = _plan_scene(plan, plan_path) if scene_path is None else _scene_file(plan, scene_path)
    placement = scene.mesh_to_turntable if scene.placed else nominal_placement(plan)
    return replace(scene, mesh_to_turntable=placement if offset is None else offset.moved(placement))


def _plan_scene(plan: PlanFile, plan_path: Path) -> SceneSpec:
    """The plan's mesh with a default material per planned region, where the plan puts it."""
    placement = mesh_to_turntable(plan)
    mesh = load_planned_mesh(plan, plan_path)
    # scene materials are indexed by position in the plan's region list
    order = {rid: i for i, rid in enumerate(region_ids(plan))}
    region = np.vectorize(order.__getitem__, otypes=[np.int64])(face_regions(plan, mesh))
    rd = srgb8_to_linear(palette(plan)) * RD_SCALE
    materials = [Material(as_triple([float(x) for x in c]), DEFAULT_RS, DEFAULT_N) for c in rd]
    if mesh.texture is None or mesh.corner_uv is None:
        return SceneSpec(mesh.vertices, mesh.faces, region, materials, placement)
    # textured: the renderer takes the material per texel; one vertex per face corner carries its UV
    # (a UV seam splits a vertex), the normals stay the welded mesh's so shading is smooth across seams
    h, w = mesh.texture.shape[:2]
    rows, cols = np.mgrid[0:h, 0:w]
    texel_uv = np.stack([(cols.ravel() + 0.5) / w, 1.0 - (rows.ravel() + 0.5) / h], axis=1)
    texel_region = np.vectorize(order.__getitem__, otypes=[np.int64])(
        texel_regions(plan, mesh.texture, texel_uv)
    )
    corners = mesh.faces.reshape(-1)
    return SceneSpec(
        mesh.vertices[corners],
        np.arange(len(corners), dtype=np.int64).reshape(-1, 3),
        region,
        materials,
        placement,
        vertex_uv=mesh.corner_uv.reshape(-1, 2),
        region_texture=texel_region.reshape(h, w),
        normals=mesh.vertex_normals[corners],
    )


@dataclass(frozen=True)
class SceneFileObject:
    """What hlr-lab reads of a sim scene file itself: the mesh (to plan, and to check against a plan) and
    the regions' colours, in the order of the scene's materials."""

    mesh: Path
    region_colours: list[tuple[int, int, int]]


def scene_file_object(scene_path: Path) -> SceneFileObject:
    """A scene file's object: its mesh path and its regions' colours; :class:`InputError` naming the file."""
    try:
        data = tomllib.loads(scene_path.read_text(encoding="utf-8"))
        mesh = scene_path.parent / data["object"]["mesh"]
        colours = [as_triple([int(c) for c in r["color"]]) for r in data.get("region", [])]  # (ValueError)
    except (OSError, KeyError, TypeError, ValueError, tomllib.TOMLDecodeError) as exc:
        raise InputError(
            f"cannot read the scene's object.mesh and region colours ({exc})", path=scene_path
        ) from exc
    return SceneFileObject(mesh, colours)


def _scene_file(plan: PlanFile, scene_path: Path) -> SceneSpec:
    mesh = scene_file_object(scene_path).mesh
    try:
        spec = load_scene(scene_path)
    except SceneError as exc:
        message = str(exc).removeprefix(
            f"{scene_path}: "
        )  # the simulator's message names the file: once will do
        raise InputError(message, path=scene_path) from exc
    if file_sha256(mesh) != plan.object.sha256:
        raise InputError(
            f"its mesh {mesh.name} is not the plan's (sha256 differs); give the scene of the planned object",
            path=scene_path,
            field="object.mesh",
        )
    return spec


def rig_file_text(dynamixel: str, modbus: str, camera: str | None, *, reply_timeout_s: float = 20.0) -> str:
    """The built-in simulated rig's file with the links of a running simulated rig filled in: what an
    operator's rig.toml is to a real bench (``hlr-lab acquire --rig`` in another process). ``camera``: the
    simulated GigE Vision camera's address (a [camera.genicam] section), or a frame endpoint "host:port"."""
    text = (resources.files("hlr_lab.data") / SIM_RIG).read_text(encoding="utf-8")
    camera_lines = f"reply_timeout_s = {reply_timeout_s}\n" if camera else ""
    if camera and ":" in camera:
        camera_lines += f'address = "{camera}"\n'
    elif camera:  # a table of its own, after every key of [camera]
        text += f'\n[camera.genicam]\ndevice = "{camera}"\nframe_timeout_s = {reply_timeout_s}\n'

    for section, lines in (
        ("[camera]", camera_lines),
        ("[gantry]", f'port = "{dynamixel}"\n'),
        ("[turntable]", f'address = "{modbus}"\n'),
    ):
        text = text.replace(f"{section}\n", f"{section}\n{lines}", 1)
    return text
