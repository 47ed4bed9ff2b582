"""The calibration targets in a simulated world: the ChArUco board on its wedge, the mirror ball and the
white reference, each where the rig file says, in the world the true rig file describes
(:class:`calibration.procedures.Targets`)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from calibration.camera_procedure import board_spec
from calibration.gantry_procedure import ball_spec
from calibration.radiometric_procedure import white_spec
from hlr_lab.files import as_pair
from hlr_lab.instrument.devices import Links
from hlr_lab.rig.file import Rig
from sim.rig import SimRig
from sim.targets import Board, Wedge, charuco_scene, mirror_ball_scene, white_reference_scene
from worlds.plan_world import world_geometry, world_links

WEDGE_TILTS_DEG = (20.0, 45.0)  # the wedge's two faces: the board leans back by these
# Samples per pixel: the board's printed edges need several (a corner is found from its edge pixels'
# coverage); a mirror's highlight is a point: it needs more. The white reference is read only in its
# middle, a matte plane whose shading changes by under 0.1 % across a pixel: one sample gives that pixel's
# value to far less than its photon noise (the procedure reads the reference's mean and the noise).
BOARD_SPP, BALL_SPP, WHITE_SPP = 8, 16, 1


@dataclass(frozen=True)
class SimulatedTargets:
    """Each target in a :class:`sim.rig.SimRig` built from ``true_rig`` (a rig file or ``builtin:NAME``;
    None: the believed rig's own file), its time ``speed_factor`` times real time."""

    true_rig: str | Path | None = None
    speed_factor: float = 1.0

    def board(self, stack: contextlib.ExitStack, rig: Rig) -> tuple[Links, Callable[[int], None]]:
        board_spec(rig)  # a rig file without a board is refused in one line
        b = rig.file.calibration.board
        assert b is not None
        board = Board(as_pair(b.squares), b.square_m, b.marker_m, b.dictionary)
        faces = [Wedge(tilt_deg=tilt, height_m=b.centre_height_m) for tilt in WEDGE_TILTS_DEG]
        world = self._world(stack, rig, charuco_scene(board, faces[0]), BOARD_SPP)
        return world_links(world), lambda face: world.show(charuco_scene(board, faces[face]))

    def mirror_ball(self, stack: contextlib.ExitStack, rig: Rig) -> Links:
        radius, place = ball_spec(rig)
        return world_links(self._world(stack, rig, mirror_ball_scene(radius, place), BALL_SPP))

    def white_reference(self, stack: contextlib.ExitStack, rig: Rig) -> Links:
        w = white_spec(rig)
        scene = white_reference_scene(tuple(w.reflectance), w.size_m, w.place_m, height_m=w.thickness_m)
        return world_links(self._world(stack, rig, scene, WHITE_SPP))

    def _world(self, stack: contextlib.ExitStack, rig: Rig, scene, spp: int) -> SimRig:
        geometry = world_geometry(rig, self.true_rig, runs=False)  # no white reference before the targets
        return stack.enter_context(SimRig(scene=scene, speed_factor=self.speed_factor, spp=spp, **geometry))
