"""The registration photographs read back from their folder: per turntable angle, the frames under each
lamp, as :class:`hlr_lab.placement.photographs.ViewFrames`. The folder is a session, so its frames are
checked as a fit checks them (:func:`hlr_lab.reflectance.session_fit.open_session`: each against its
journal line and checksum; missing ones are refused, naming them)."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PlanFile
from hlr_lab.placement.photographs import Sensor, ViewFrames
from hlr_lab.reflectance.session_fit import bracket_frame, open_session
from hlr_lab.rig.file import Rig


@dataclass(frozen=True, eq=False)
class Photographs:
    """A registration folder's views, what reading their frames needs, and the rig that took them (its
    snapshot in the session: the camera the outlines are measured with)."""

    views: list[ViewFrames]
    sensor: Sensor
    rig: Rig
    plan: PlanFile  # the registration plan


def read_photographs(folder: Path) -> Photographs:
    """The views of the registration in ``folder``, each lamp's frames longest exposure first."""
    session = open_session(folder, correct_lamp=False)
    rig = session.rig
    by_turn: dict[int, list] = defaultdict(list)
    for view in session.views:
        by_turn[int(view.measured["turntable_steps"])].append(view)
    views, bits = [], set()
    for steps, lamps in sorted(by_turn.items()):
        brackets, exposures = [], None
        for view in sorted(lamps, key=lambda v: v.pose):
            frames = sorted(
                (bracket_frame(folder, e, view.sidecars[e["file"]], None, rig) for e in view.frames),
                key=lambda f: -f.exposure_s,
            )
            these = np.array([f.exposure_s for f in frames])
            if exposures is None:
                exposures = these
            if len(these) != len(exposures) or not np.allclose(these, exposures, rtol=1e-6):
                raise InputError(
                    f"pose {view.pose} was exposed for {these.tolist()} s, the others of its view for "
                    f"{exposures.tolist()} s: these are not one registration's photographs",
                    path=folder,
                )
            bits.update(f.bits for f in frames)
            brackets.append(np.stack([f.pixels for f in frames]))
        assert exposures is not None  # every view has frames (open_session keeps only those)
        views.append(ViewFrames(rig.turntable_kinematics.degrees_for(steps), np.stack(brackets), exposures))
    if len(bits) > 1:
        raise InputError(f"its frames were taken at {sorted(bits)} bits: not one camera's", path=folder)
    sensor = rig.file.sensor
    full = float((1 << bits.pop()) - 1) if bits else 0.0
    return Photographs(views, Sensor(sensor.black_level_dn, sensor.read_noise_dn, full), rig, session.plan)
