"""Cameras for tests that render: the simulated rig's camera at a smaller film."""

from __future__ import annotations

from hlr_lab.geometry.camera import Camera
from hlr_lab.rig.file import sim_rig


def half_size_camera(aspect: float = 1.0) -> Camera:
    """The sim rig's camera at 640×480: off-centre principal point and barrel distortion kept; ``aspect``
    fy / fx (a calibrated camera's pixels are seldom exactly square)."""
    c = sim_rig().camera
    k = c.matrix.copy()
    k[:2] /= 2
    k[1, 1] *= aspect
    return Camera(k, c.distortion, c.rotation, c.translation, 640, 480)
