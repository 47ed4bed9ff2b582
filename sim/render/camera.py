"""An OpenCV camera (K, distortion, world → camera pose) rendered by Mitsuba, on its own pixel grid
(:mod:`sim.render.opencv_sensor`: each ray undistorted where it leaves the camera, no resampling).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

SENSOR_PLUGIN = "hlr_opencv_camera"  # sim.render.opencv_sensor, registered once Mitsuba's variant is set
COEFFICIENTS = ("k1", "k2", "p1", "p2", "k3")  # OpenCV's distortion, in its order


@dataclass(frozen=True, eq=False)
class CameraSpec:
    """matrix (3, 3), distortion (k,), rotation (3, 3) and translation (3,) world → camera (OpenCV), size."""

    matrix: np.ndarray
    distortion: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    width: int
    height: int

    @property
    def centre(self) -> np.ndarray:
        return -self.rotation.T @ self.translation


class CameraFilm:
    """The Mitsuba sensor of a :class:`CameraSpec`, and where on its film an object lands."""

    def __init__(self, cam: CameraSpec):
        k = np.asarray(cam.matrix, np.float64)
        if abs(k[0, 1]) > 1e-12:
            raise ValueError("the simulated camera has no skew (K[0,1] = 0), as OpenCV's camera model")
        coeffs = np.asarray(cam.distortion, np.float64).ravel()
        if np.any(coeffs[len(COEFFICIENTS) :]):
            raise ValueError("the simulated camera's distortion has at most 5 coefficients (k1 k2 p1 p2 k3)")
        self.distortion = np.zeros(len(COEFFICIENTS))
        self.distortion[: min(len(coeffs), len(COEFFICIENTS))] = coeffs[: len(COEFFICIENTS)]
        self.width, self.height = cam.width, cam.height
        self.cam = cam

    def sensor_dict(self, spp: int) -> dict:
        """The camera as :mod:`sim.render.opencv_sensor`'s sensor, its film the camera's image (box filter:
        a pixel is the mean of the radiance over its square)."""
        import mitsuba as mi

        cam, k = self.cam, self.cam.matrix
        to_world = np.eye(4)
        to_world[:3, :3] = cam.rotation.T  # camera axes (x right, y down, z forward) in the world
        to_world[:3, 3] = cam.centre
        return {
            "type": SENSOR_PLUGIN,
            "fx": float(k[0, 0]),
            "fy": float(k[1, 1]),
            "cx": float(k[0, 2]),
            "cy": float(k[1, 2]),
            **{name: float(c) for name, c in zip(COEFFICIENTS, self.distortion, strict=True)},
            "to_world": mi.ScalarTransform4f(to_world.tolist()),
            "film": {
                "type": "hdrfilm",
                "width": self.width,
                "height": self.height,
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            },
            "sampler": {"type": "independent", "sample_count": int(spp)},
        }

    def object_box(self, points: np.ndarray, margin: int = 2) -> tuple[int, int, int, int]:
        """(x, y, width, height) of the image holding the projection of world ``points`` (N, 3), plus a
        margin; the whole image if any point is behind the camera."""
        cam = self.cam
        if ((points @ cam.rotation.T + cam.translation)[:, 2] <= 0).any():
            return 0, 0, self.width, self.height
        uv, _ = cv2.projectPoints(
            np.asarray(points, np.float64), cv2.Rodrigues(np.asarray(cam.rotation, np.float64))[0],
            np.asarray(cam.translation, np.float64), np.asarray(cam.matrix, np.float64), self.distortion,
        )  # fmt: skip
        u, v = uv.reshape(-1, 2).T
        x0, y0 = (max(0, int(np.floor(a.min())) - margin) for a in (u, v))
        x1 = min(self.width, int(np.ceil(u.max())) + margin + 1)
        y1 = min(self.height, int(np.ceil(v.max())) + margin + 1)
        if x1 <= x0 or y1 <= y0:
            return 0, 0, 1, 1  # entirely off the image: render one pixel of nothing
        return x0, y0, x1 - x0, y1 - y0
