"""The simulated rig on its own: served for any client (``hlr-lab sim serve``), or examined as a real
rig is (``hlr-lab doctor --sim``)."""

from __future__ import annotations

from dataclasses import replace

from hlr_lab.errors import InputError
from hlr_lab.instrument.doctor import Finding, examine_rig
from hlr_lab.rig.file import Rig, sim_rig
from sim.render.scene import SceneError, builtin_scene, load_scene
from sim.rig import SimRig
from sim.targets import mirror_ball_scene
from worlds.plan_world import ObjectOffset, world_geometry


def served_world(
    scene_spec: str | None, true_rig: str | None, speed_factor: float, offset: ObjectOffset | None = None
) -> SimRig:
    """The built-in rig's simulated devices (not yet started: enter it), built as ``true_rig`` says, with
    a camera photographing ``scene_spec`` (a scene file or builtin:NAME; None: no camera), its object where
    the scene puts it (its ``placed``), moved by ``offset``."""
    scene = None
    if scene_spec:
        try:
            scene = builtin_scene(scene_spec) if scene_spec.startswith("builtin:") else load_scene(scene_spec)
        except SceneError as exc:
            raise InputError(str(exc), field="--scene") from exc
        if offset is not None:
            scene = replace(scene, mesh_to_turntable=offset.moved(scene.mesh_to_turntable))
    elif offset is not None:
        raise InputError("moves the served scene's object: give --scene too", field="--object-offset")
    geometry = world_geometry(sim_rig(), true_rig)  # the camera is made only with a scene
    return SimRig(speed_factor=speed_factor, scene=scene, **geometry)


def examine_simulated(rig: Rig) -> list[Finding]:
    """:func:`hlr_lab.instrument.doctor.examine_rig` on a simulated world built as ``rig`` says, started
    for the purpose and stopped again."""
    scene = mirror_ball_scene(
        0.02, (0.0, 0.0)
    )  # any scene gives the world its camera (opening it takes no photograph)
    with SimRig(scene=scene, **world_geometry(rig, runs=False)) as world:
        e = world.endpoints
        return examine_rig(rig, gantry_port=e.dynamixel, stage_address=e.modbus, camera_endpoint=e.camera)
