"""Calibration targets the simulated camera can photograph: a ChArUco board on a wedge on the turntable,
a mirror ball and a white reference lying on the plate.

The board is printed with OpenCV's own aruco module (so its markers are exactly what a detector expects)
onto a flat quad: a two-material textured scene (black ink, white paper; both matte), which the
renderer samples per texel, so square edges fall where they fall, not on mesh edges.

Board frame (OpenCV's): origin at the board's top-left chessboard corner as printed, x along the rows
of squares, y down the printed image, z into the board; the printed face looks along −z. The wedge
stands the board on the turntable facing −y (toward a camera on the −y side), leaning back by
``tilt_deg`` from vertical, its centre ``height_m`` above the plate on the axis, then turned
``azimuth_deg`` about the plate's axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sim.render.scene import Material, MirrorBall, SceneSpec
from sim.tuples import triple

INK, PAPER = (
    Material((0.04, 0.04, 0.04), (0.0, 0.0, 0.0), 1.0),
    Material((0.8, 0.8, 0.8), (0.0, 0.0, 0.0), 1.0),
)


@dataclass(frozen=True)
class Board:
    """A ChArUco board as printed: squares across (x) and down (y), their side and the markers' side in
    metres, and the ArUco dictionary by OpenCV's name."""

    squares: tuple[int, int] = (11, 8)
    square_m: float = 0.025
    marker_m: float = 0.018
    dictionary: str = "DICT_4X4_50"

    @property
    def size_m(self) -> tuple[float, float]:
        return self.squares[0] * self.square_m, self.squares[1] * self.square_m

    def printed(self, px_per_square: int) -> np.ndarray:
        """(H, W) uint8: the board as OpenCV draws it, ``px_per_square`` texels per square."""
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        board = cv2.aruco.CharucoBoard(self.squares, self.square_m, self.marker_m, d)
        w, h = (n * px_per_square for n in self.squares)
        return board.generateImage((w, h), marginSize=0, borderBits=1)


@dataclass(frozen=True)
class Wedge:
    """Where the board stands on the turntable (see the module's docstring)."""

    tilt_deg: float = 25.0
    height_m: float = 0.09
    azimuth_deg: float = 0.0

    def board_to_turntable(self, board: Board) -> np.ndarray:
        """(4, 4) board frame → turntable frame."""
        t = np.radians(self.tilt_deg)
        x = np.array([1.0, 0.0, 0.0])
        y = np.array([0.0, -np.sin(t), -np.cos(t)])  # down the printed image: down the slope
        z = np.cross(x, y)  # into the board: the printed face looks the other way, toward −y and up
        w, h = board.size_m
        centre = np.array([0.0, 0.0, self.height_m])
        m = np.eye(4)
        m[:3, :3] = np.stack([x, y, z], axis=1)
        m[:3, 3] = centre - m[:3, :3] @ np.array([w / 2, h / 2, 0.0])
        a = np.radians(self.azimuth_deg)
        turn = np.eye(4)
        turn[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        return turn @ m


def charuco_scene(board: Board, wedge: Wedge, *, px_per_square: int = 120, power: float = 1.0) -> SceneSpec:
    """The board on its wedge as a textured scene (two matte materials: ink and paper)."""
    image = board.printed(px_per_square)
    h, w = image.shape
    bw, bh = board.size_m
    vertices = np.array([[0.0, 0.0, 0.0], [bw, 0.0, 0.0], [bw, bh, 0.0], [0.0, bh, 0.0]])
    uv = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])  # OBJ convention: v up, row 0 at v = 1
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # wound so the geometric normal is −z: the printed face
    region_texture = (image > 127).astype(np.int64)  # 0 ink, 1 paper
    assert region_texture.shape == (h, w)
    return SceneSpec(
        vertices,
        faces,
        np.zeros(len(faces), np.int64),
        [INK, PAPER],
        wedge.board_to_turntable(board),
        power=power,
        vertex_uv=uv,
        region_texture=region_texture,
        normals=np.tile([0.0, 0.0, -1.0], (4, 1)),
    )


def mirror_ball_scene(
    radius_m: float, centre_xy_m: tuple[float, float], *, plate_radius_m: float = 0.35, plate_rd: float = 0.5
) -> SceneSpec:
    """A polished ball of ``radius_m`` resting on the turntable's plate at ``centre_xy_m``, and the plate:
    a matte grey disc, against which the (otherwise black) ball shows its outline."""
    angles = np.linspace(0.0, 2 * np.pi, 97)[:-1]
    rim = np.stack(
        [plate_radius_m * np.cos(angles), plate_radius_m * np.sin(angles), np.zeros_like(angles)], 1
    )
    vertices = np.vstack([[0.0, 0.0, 0.0], rim])
    n = len(angles)
    faces = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])  # counter-clockwise seen from above
    plate = Material((plate_rd, plate_rd, plate_rd), (0.0, 0.0, 0.0), 1.0)
    ball = MirrorBall((float(centre_xy_m[0]), float(centre_xy_m[1]), radius_m), radius_m)
    return SceneSpec(vertices, faces, np.zeros(n, np.int64), [plate], np.eye(4), mirror_balls=(ball,),
                     normals=np.tile([0.0, 0.0, 1.0], (len(vertices), 1)))  # fmt: skip


def white_reference_scene(
    reflectance: tuple[float, float, float],
    size_m: float,
    centre_xy_m: tuple[float, float],
    *,
    height_m: float = 0.0,
    plate_radius_m: float = 0.35,
    plate_rd: float = 0.05,
) -> SceneSpec:
    """A flat Lambertian square of ``reflectance`` (per channel) and side ``size_m`` lying on the plate
    with its centre at ``centre_xy_m`` and its face ``height_m`` above the plate (half a millimetre at
    least: two surfaces in one plane would flicker), and the plate: a dark matte disc around it."""
    angles = np.linspace(0.0, 2 * np.pi, 97)[:-1]
    n = len(angles)
    rim = np.stack([plate_radius_m * np.cos(angles), plate_radius_m * np.sin(angles), np.zeros(n)], 1)
    x, y, h, z = float(centre_xy_m[0]), float(centre_xy_m[1]), size_m / 2, max(height_m, 5e-4)
    square = np.array([[x - h, y - h, z], [x + h, y - h, z], [x + h, y + h, z], [x - h, y + h, z]])
    vertices = np.vstack([[0.0, 0.0, 0.0], rim, square])
    plate_faces = [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]  # counter-clockwise seen from above
    s = n + 1
    faces = np.array([*plate_faces, [s, s + 1, s + 2], [s, s + 2, s + 3]])
    regions = np.array([0] * n + [1, 1], np.int64)
    materials = [Material((plate_rd, plate_rd, plate_rd), (0.0, 0.0, 0.0), 1.0),
                 Material(triple(float(r) for r in reflectance), (0.0, 0.0, 0.0), 1.0)]  # fmt: skip
    return SceneSpec(vertices, faces, regions, materials, np.eye(4),
                     normals=np.tile([0.0, 0.0, 1.0], (len(vertices), 1)))  # fmt: skip
