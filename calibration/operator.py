"""The operator's targets: on a real rig a person puts each target where the rig file says, asked
through ``confirm`` (the command line's prompt; a refusal raises there and nothing moves)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass

from hlr_lab.instrument.devices import Links
from hlr_lab.rig.file import Rig


@dataclass(frozen=True)
class OperatorTargets:
    """:class:`calibration.procedures.Targets` for a person at the rig; the rig file's own links.

    Parameters
    ----------
    confirm
        Asks the question and returns once the operator says the target is in place (its value unused;
        a refusal raises).
    """

    confirm: Callable[[str], object]

    def board(self, stack: contextlib.ExitStack, rig: Rig) -> tuple[Links, Callable[[int], None]]:
        def turn(face: int) -> None:
            what = (
                "on the wedge's first face"
                if face == 0
                else "on the wedge's other face (turn the wedge over)"
            )
            self.confirm(f"Put the board {what}, facing the camera. Ready?")

        return Links(), turn

    def mirror_ball(self, stack: contextlib.ExitStack, rig: Rig) -> Links:
        self.confirm("Put the mirror ball on the plate where the rig file says. Ready?")
        return Links()

    def white_reference(self, stack: contextlib.ExitStack, rig: Rig) -> Links:
        self.confirm("Put the white reference on the plate where the rig file says. Ready?")
        return Links()
