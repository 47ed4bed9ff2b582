"""The camera model: OpenCV pinhole intrinsics + distortion, and a pose (world → camera).

Camera frame as OpenCV: x right, y down, z forward. Pixel centres are at integer coordinates
(OpenCV's convention), so pixel (0, 0) covers [-0.5, 0.5]².
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np


@dataclass(frozen=True, eq=False)
class Camera:
    """matrix (3, 3) K; distortion (k,) OpenCV coefficients (k1, k2, p1, p2[, k3]);
    rotation (3, 3) and translation (3,) map world points into the camera frame: x_c = R x_w + t."""

    matrix: np.ndarray
    distortion: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    width: int
    height: int
    _dist5: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        d = np.zeros(5)
        coeffs = np.asarray(self.distortion, dtype=np.float64).ravel()
        if len(coeffs) > 5:
            raise ValueError("only the k1, k2, p1, p2, k3 distortion model is supported")
        d[: len(coeffs)] = coeffs
        object.__setattr__(self, "_dist5", d)

    @classmethod
    def look_at(
        cls,
        position,
        target,
        *,
        matrix,
        width: int,
        height: int,
        distortion=(),
        up=(0.0, 0.0, 1.0),
        roll_deg=0.0,
    ):
        """A camera at ``position`` looking at ``target`` with world ``up`` pointing up in the image, then
        turned ``roll_deg`` about its optical axis (right-handed about +z: x → cos·x + sin·y)."""
        position, target, up = (np.asarray(a, dtype=np.float64) for a in (position, target, up))
        z = target - position
        z /= np.linalg.norm(z)
        x = np.cross(z, up)
        if np.linalg.norm(x) < 1e-9:
            raise ValueError("the viewing direction is parallel to 'up'; choose another up vector")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
        rotation = np.stack([c * x + s * y, c * y - s * x, z])
        return cls(
            np.asarray(matrix, float),
            np.asarray(distortion, float),
            rotation,
            -rotation @ position,
            int(width),
            int(height),
        )

    @property
    def centre(self) -> np.ndarray:
        """(3,) the optical centre in world coordinates."""
        return -self.rotation.T @ self.translation

    @property
    def forward(self) -> np.ndarray:
        """(3,) the optical axis in world coordinates."""
        return self.rotation[2]

    def in_frame(self, world_from_frame: np.ndarray) -> Camera:
        """The same physical camera expressed in another frame; ``world_from_frame`` is 4×4 rigid."""
        a, b = world_from_frame[:3, :3], world_from_frame[:3, 3]
        return Camera(
            self.matrix,
            self.distortion,
            self.rotation @ a,
            self.rotation @ b + self.translation,
            self.width,
            self.height,
        )

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points → (N, 3) camera-frame points."""
        return points @ self.rotation.T + self.translation

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) world points → pixels (N, 2) and depth z (N,); distortion applied as OpenCV does.

        Points behind the camera (z ≤ 0) get NaN pixels.
        """
        pc = self.to_camera(np.asarray(points, dtype=np.float64))
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = pc[:, 0] / z, pc[:, 1] / z
        k1, k2, p1, p2, k3 = self._dist5
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        k = self.matrix
        uv = np.stack([k[0, 0] * xd + k[0, 1] * yd + k[0, 2], k[1, 1] * yd + k[1, 2]], axis=1)
        uv[z <= 0] = np.nan
        return uv, z

    def in_image(self, pixels: np.ndarray) -> np.ndarray:
        """(N,) bool: the pixel lies on the sensor."""
        u, v = pixels[:, 0], pixels[:, 1]
        with np.errstate(invalid="ignore"):
            return (u >= -0.5) & (u < self.width - 0.5) & (v >= -0.5) & (v < self.height - 0.5)

    def pixel_rays(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) pixels → ray origins (N, 3) and unit directions (N, 3) in world coordinates."""
        return self._rays(_normalised(np.asarray(pixels, dtype=np.float64), self.matrix, self._dist5))

    def grid_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """``pixel_rays(pixel_grid())``: (H·W, 3) origins and unit directions through every pixel centre. The
        grid's undistortion is kept for the last two intrinsics asked (a G-buffer per view of one camera:
        it was 0.2 s of a 1280 × 960 G-buffer's 0.37 s)."""
        key = (self.matrix.astype(np.float64).tobytes(), self._dist5.tobytes(), self.width, self.height)
        return self._rays(_grid_normalised(*key))

    def _rays(self, norm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) undistorted normalised image points → world origins (N, 3) and unit directions (N, 3)."""
        d_cam = np.concatenate([norm, np.ones((len(norm), 1))], axis=1)
        d_world = d_cam @ self.rotation  # R^T d for each row
        d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
        return np.broadcast_to(self.centre, d_world.shape).copy(), d_world

    def pixel_grid(self) -> np.ndarray:
        """(H·W, 2) every pixel centre, row-major (row = v)."""
        return _pixel_centres(self.width, self.height)

    def projected_area_px(self, points: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> np.ndarray:
        """(N,) image area in pixels of small surface patches.

        The patch subtends a solid angle area·cos(view angle)/d²; on the image plane (z = 1) that solid
        angle covers 1/cos³φ as much at an angle φ off the optical axis, and cos φ = z/d, so the area is
        area·cos(view)·d/z³, times fx·fy for pixels. The distortion's local magnification is ignored
        (a few per cent at the image corners).
        """
        pc = self.to_camera(points)
        z = pc[:, 2]
        to_cam = self.centre - points
        dist = np.linalg.norm(to_cam, axis=1)
        cos_view = np.einsum("ij,ij->i", normals, to_cam) / np.maximum(dist, 1e-300)
        zpos = np.maximum(z, 1e-300)
        return np.where(
            z > 0,
            areas * np.clip(cos_view, 0, None) * dist / zpos**3 * self.matrix[0, 0] * self.matrix[1, 1],
            0.0,
        )


def _normalised(pixels: np.ndarray, matrix: np.ndarray, dist5: np.ndarray) -> np.ndarray:
    """(N, 2) pixels → (N, 2) undistorted normalised image points (x/z, y/z) of the camera ``matrix`` (3, 3)
    with distortion ``dist5`` (5,)."""
    pts = pixels.reshape(-1, 1, 2)
    if np.any(dist5):
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        # OpenCV 4; 5 folded it into undistortPoints
        undistort_iter = getattr(cv2, "undistortPointsIter", None)
        if undistort_iter is not None:
            norm = undistort_iter(pts, matrix, dist5, None, None, criteria)
        else:
            norm = cv2.undistortPoints(pts, matrix, dist5, R=None, P=None, criteria=criteria)
        return norm.reshape(-1, 2)
    y = (pts[:, 0, 1] - matrix[1, 2]) / matrix[1, 1]
    x = (pts[:, 0, 0] - matrix[0, 2] - matrix[0, 1] * y) / matrix[0, 0]
    return np.stack([x, y], axis=1)


@functools.lru_cache(maxsize=2)
def _grid_normalised(matrix: bytes, dist5: bytes, width: int, height: int) -> np.ndarray:
    """(H·W, 2) :func:`_normalised` of every pixel centre, read-only (20 MB at 1280 × 960)."""
    norm = _normalised(
        _pixel_centres(width, height), np.frombuffer(matrix).reshape(3, 3), np.frombuffer(dist5)
    )
    norm.flags.writeable = False
    return norm


def _pixel_centres(width: int, height: int) -> np.ndarray:
    """(H·W, 2) float64 every pixel centre (u, v), row-major (row = v)."""
    v, u = np.mgrid[0:height, 0:width]
    return np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
