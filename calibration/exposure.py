"""Finding an exposure: photograph, measure, rescale, until the measured level sits where a procedure
wants it. Each calibration procedure measures its own level (the brightest paper, the plate behind the
ball, the highlight's peak, the white reference's middle) and says how near is near enough."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.protocols import Camera, RawFrame


@dataclass(frozen=True)
class ExposureGoal:
    """What a frame should show: ``level(pixels)`` near ``fill`` of full scale, accepted within ``accept``
    (fractions of full scale, exclusive); a level at or above ``clipped_at`` of full scale says nothing
    about how far over it is, so the exposure is multiplied by ``clipped_factor`` instead."""

    level: Callable[[np.ndarray], float]
    fill: float
    accept: tuple[float, float]
    clipped_at: float = 1.0
    clipped_factor: float = 0.25
    tries: int = 4


def exposed(camera: Camera, exposure_s: float, goal: ExposureGoal) -> RawFrame:
    """The first frame, from ``exposure_s`` on, whose level ``goal`` accepts (each miss rescales the
    exposure toward ``goal.fill``); after ``goal.tries`` frames, the last one."""
    tried = 0
    while True:
        camera.set_exposure(exposure_s)
        frame = camera.capture()
        tried += 1
        top = (1 << frame.bits) - 1
        level = float(goal.level(frame.pixels))
        lo, hi = goal.accept
        if (level < goal.clipped_at * top and lo * top < level < hi * top) or tried >= goal.tries:
            return frame
        clipped = level >= goal.clipped_at * top
        exposure_s = frame.exposure_s * (
            goal.clipped_factor if clipped else goal.fill * top / max(level, 1.0)
        )
