"""An OpenCV camera (K, distortion, world → camera pose) rendered by Mitsuba.

Mitsuba's perspective sensor is an ideal pinhole with square pixels: the render is made on a slightly
larger undistorted film with square pixels (focal length fx), then warped with the distortion and the
pixels' aspect (fy / fx) by remapping (OpenCV), so that pixel (u, v) sees what a real camera with these
intrinsics would.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


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


class PinholeFilm:
    """The undistorted film Mitsuba renders, and the map that distorts it into the camera's image."""

    def __init__(self, cam: CameraSpec):
        k = np.asarray(cam.matrix, np.float64)
        if abs(k[0, 1]) > 1e-12:
            raise ValueError("the simulated camera has no skew (K[0,1] = 0), as OpenCV's camera model")
        self.f = k[0, 0]
        square = np.array([[self.f, 0.0, k[0, 2]], [0.0, self.f, k[1, 2]], [0.0, 0.0, 1.0]])
        dist = np.zeros(5)
        coeffs = np.asarray(cam.distortion, np.float64).ravel()
        dist[: len(coeffs)] = coeffs
        v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float32)
        pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        remapped = bool(np.any(dist)) or k[1, 1] != self.f  # the camera's pixels are not the film's
        if remapped:  # where each camera pixel's ray meets the square-pixel film
            ideal = cv2.undistortPoints(pixels, k, dist, P=square).reshape(cam.height, cam.width, 2)
        else:
            ideal = pixels.reshape(cam.height, cam.width, 2)
        # a margin so that every distorted pixel finds its ideal source on the film
        lo = np.floor(ideal.reshape(-1, 2).min(axis=0)) - 2
        hi = np.ceil(ideal.reshape(-1, 2).max(axis=0)) + 2
        self.offset = np.minimum(lo, 0)  # film pixel (0, 0) is camera pixel `offset`
        size = np.maximum(hi, [cam.width - 1, cam.height - 1]) - self.offset + 1
        self.width, self.height = int(size[0]), int(size[1])
        self.cx, self.cy = k[0, 2] - self.offset[0], k[1, 2] - self.offset[1]
        self.map = (ideal - self.offset).astype(np.float32)
        self.distorted = remapped or self.width != cam.width or self.height != cam.height
        self.cam = cam

    def sensor_dict(self, spp: int) -> dict:
        """Mitsuba perspective sensor: horizontal field of view from f; principal point as an offset from
        the film centre in film-size fractions, counted the other way from OpenCV's pixel axes (measured:
        with the OpenCV sign the image lands shifted by twice the offset); camera frame x left, y up,
        z forward."""
        import mitsuba as mi

        cam = self.cam
        fov_x = np.degrees(2 * np.arctan(self.width / (2 * self.f)))
        to_world = np.eye(4)
        to_world[:3, :3] = cam.rotation.T @ np.diag([-1.0, -1.0, 1.0])  # OpenCV x right, y down → Mitsuba
        to_world[:3, 3] = cam.centre
        return {
            "type": "perspective",
            "fov": float(fov_x),
            "fov_axis": "x",
            "principal_point_offset_x": float(-(self.cx - (self.width - 1) / 2) / self.width),
            "principal_point_offset_y": float(-(self.cy - (self.height - 1) / 2) / self.height),
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
        """(x, y, width, height) on the film holding the projection of world ``points`` (N, 3), plus a
        margin; the whole film if any point is behind the camera."""
        pc = points @ self.cam.rotation.T + self.cam.translation
        if (pc[:, 2] <= 0).any():
            return 0, 0, self.width, self.height
        u = self.f * pc[:, 0] / pc[:, 2] + self.cx
        v = self.f * pc[:, 1] / pc[:, 2] + self.cy
        x0, y0 = (max(0, int(np.floor(a.min())) - margin) for a in (u, v))
        x1 = min(self.width, int(np.ceil(u.max())) + margin + 1)
        y1 = min(self.height, int(np.ceil(v.max())) + margin + 1)
        if x1 <= x0 or y1 <= y0:
            return 0, 0, 1, 1  # entirely off the film: render one pixel of nothing
        return x0, y0, x1 - x0, y1 - y0

    def to_camera_image(self, film: np.ndarray) -> np.ndarray:
        """(film H, film W, 3) → (H, W, 3) as the real (distorted) camera sees it."""
        if not self.distorted:
            return film
        return cv2.remap(
            film,
            self.map[..., 0],
            self.map[..., 1],
            interpolation=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
        )
