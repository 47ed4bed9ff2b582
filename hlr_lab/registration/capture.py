"""The registration photographs: a plan of its own (six turntable angles × the four registration lamps ×
the rig's exposure bracket), run as any plan is (:func:`hlr_lab.acquisition.run.acquire_session`: the
motions checked against the rig's limits before anything moves, every frame journaled, the rig left safe
on every exit, a stopped run resumed), into a folder that is a session (docs/sessions.md) with the
registration plan beside its files. ``--from`` reads the photographs back from there alone
(:mod:`hlr_lab.registration.views`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from hlr_lab.acquisition.poses import Bracketing, Outcome, Step
from hlr_lab.acquisition.run import acquire_session
from hlr_lab.errors import InputError
from hlr_lab.files import atomic_write_bytes, model_json
from hlr_lab.formats.plan import PlanFile, PlanLight, PlanPose, read_plan
from hlr_lab.formats.planned_object import mesh_to_turntable
from hlr_lab.formats.regions import mesh_reference
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.instrument.devices import Links
from hlr_lab.instrument.motion import motion_targets
from hlr_lab.object.procedural import BUILTIN_PREFIX
from hlr_lab.placement.photographs import registration_lamps
from hlr_lab.rig.file import Rig
from hlr_lab.session.metadata import SESSION

REGISTRATION_PLAN = "registration-plan.json"  # in the photographs' folder
VIEWS = 6  # turntable angles: each shows the outline from another side
# the bracket is the plan's: no frame added when something clips (a clipped highlight is still lit, and
# every lamp of a view then has the same exposures)
REGISTRATION_BRACKET = Bracketing(max_extra=0)


def registration_views(rig: Rig, count: int = VIEWS) -> list[float]:
    """(count,) turntable angles (degrees) a turn apart by 360°/count, within the turntable's limits; on a
    turntable that cannot turn that far, spread over its range."""
    lo, hi = rig.turntable_limits_deg
    step = 360.0 / count
    if hi - lo >= step * (count - 1):
        return [lo + step * k for k in range(count)]
    return [float(a) for a in np.linspace(lo, hi, count)]


def registration_plan(plan: PlanFile, plan_path: Path, rig: Rig, folder: Path) -> PlanFile:
    """The plan of the registration photographs of ``plan``'s object (read from ``plan_path``), to be
    written in ``folder``: its object and parameters, poses ``v{k}-l{j}`` (view k, lamp j), no coverage."""
    placement = mesh_to_turntable(plan)
    mesh_from_tt = np.linalg.inv(placement)
    kinematics = rig.gantry.kinematics
    poses = []
    for k, turn in enumerate(registration_views(rig)):
        # the world at this turn → the mesh's frame
        to_mesh = mesh_from_tt @ np.linalg.inv(rotation_z(np.radians(turn)))
        lamps = list(enumerate(registration_lamps(rig)))
        for j, (az, el) in lamps if k % 2 == 0 else lamps[::-1]:  # back the way it came: no return swing
            lamp = kinematics.centre + kinematics.arm_radius * kinematics.unit_direction(
                np.radians(az), np.radians(el)
            )
            poses.append(
                PlanPose(
                    id=f"v{k}-l{j}",
                    turntable_deg=round(turn, 6),
                    light=PlanLight(
                        azimuth_deg=round(float(az), 4),
                        elevation_deg=round(float(el), 4),
                        position_m=_rounded(lamp),
                        position_mesh_m=_rounded(to_mesh[:3, :3] @ lamp + to_mesh[:3, 3]),
                    ),
                    camera_position_mesh_m=_rounded(to_mesh[:3, :3] @ rig.camera.centre + to_mesh[:3, 3]),
                    exposures_s=list(rig.exposure_bracket_s),
                    expected={},
                )
            )
    ref, texture = plan.object.mesh, plan.object.texture
    moved = {
        "mesh": ref if ref.startswith(BUILTIN_PREFIX) else mesh_reference(plan_path.parent / ref, folder),
        "texture": None if texture is None else mesh_reference(plan_path.parent / texture, folder),
    }
    return PlanFile(
        format=plan.format,
        version=plan.version,
        object=plan.object.model_copy(update=moved),
        parameters=plan.parameters,
        poses=poses,
        coverage={},
    )


def _rounded(p: np.ndarray) -> list[float]:
    """A position (3,) in metres as plan.json keeps it (to the µm)."""
    return [round(float(v), 6) for v in p]


def capture_views(
    plan: PlanFile,
    plan_path: Path,
    rig: Rig,
    folder: Path,
    *,
    links: Links,
    progress: Callable[[Step], None] = lambda _: None,
    on_start: Callable[[bool], None] = lambda _resumed: None,
) -> Outcome:
    """Photograph ``plan``'s object for registration into ``folder`` (new, or the folder of a stopped
    registration of the same plan on the same rig: it resumes). Refuses, before anything moves, a rig
    whose gantry cannot reach the registration lamps and a folder that holds another registration."""
    if rig.file.lamp is None:
        raise InputError(
            "registration switches the lamp: add a [lamp] section", path=rig.source, field="lamp"
        )
    wanted = registration_plan(plan, plan_path, rig, folder)
    path = folder / REGISTRATION_PLAN
    text = model_json(wanted).encode()
    if path.exists() and path.read_bytes() != text:
        raise InputError(
            "holds the photographs of another plan or rig (its registration plan differs): give a new --out, "
            "or --from to solve again from them",
            path=folder,
        )
    targets = motion_targets(wanted, rig, path)  # the lamps within the gantry's limits, before any file
    # a folder of its own: new, a registration's, or one refused before its session began (its plan alone:
    # a disk too full, say)
    foreign = [e.name for e in folder.iterdir() if e.name != REGISTRATION_PLAN] if folder.exists() else []
    if foreign and not (folder / SESSION).exists():
        raise InputError("is not empty and holds no registration: give a new --out", path=folder)
    folder.mkdir(parents=True, exist_ok=True)
    if not path.exists():
        atomic_write_bytes(path, text)
    return acquire_session(read_plan(path), path, targets, rig, folder, links=links,
                           bracket=REGISTRATION_BRACKET, progress=progress, on_start=on_start)  # fmt: skip
