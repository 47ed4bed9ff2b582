"""Where the object lies, from its outlines: a search over turns about the axis, then a least-squares fit of
the six numbers of :class:`~hlr_lab.placement.pose.PlacementFrame`, and of the photographed outline's offset
all round (:data:`MAX_OUTLINE_OFFSET_PX`), to the outlines of every view.

The outline of a polygon mesh is made of its *contour edges* (one neighbouring face toward the camera, one
away) that are not hidden: points along them, about a pixel apart, lie exactly on the silhouette's border.
Each view's photographed mask gives a signed distance to its border (pixels, positive outside); the fit
moves the object until the contour points' distances are zero in every view — an ICP on silhouettes, the
contour points chosen again after each fit, differentiable in the six numbers between choices. The search
scores every 10° about the axis by the masks' overlap and refines the best three (each two steps from the
others); a second minimum as good as the first far from it, or a turn the outlines hardly see (a round
object), is reported as ambiguous rather than guessed. docs/placement.md says what it cannot see.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from hlr_lab.errors import PlacementError
from hlr_lab.geometry.camera import Camera
from hlr_lab.geometry.raster import ONE_PX, corner_pixels, fill_triangles
from hlr_lab.geometry.silhouette import signed_distance
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.geometry.vectors import lengths
from hlr_lab.object.clusters import cluster_vertices, clustered_mesh
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.raycast import PixelSurface, RayCaster
from hlr_lab.placement.photographs import ObservedView
from hlr_lab.placement.pose import PlacementFrame, local_difference, nudged, yaw_params

YAW_STEP_DEG = 10.0  # the search's step about the axis: a mask overlaps its own 5° turn by ≳ 90 %
CANDIDATES = 3  # yaws refined from the search's best scores
SEARCH_SCALE = 4  # the search compares masks at 1/4 of the image's resolution
SEARCH_SAMPLES = 40_000  # surface points that stand in for the mesh there (≳ 2 per pixel of its image)
POINT_SPACING_PX = 1.0  # contour points along an edge: about one a pixel
OUTLINE_PX = 1.5  # a contour point within this of the predicted mask's border is on the outline
ROBUST_PX = 1.0  # soft-L1 scale of the outline residuals (px): a mask's border is known to ~0.5 px
MAX_SHIFT_MM = 30.0  # the search range: off the axis, in the plate's plane
MAX_TILT_DEG = 5.0  # and tilted from how the plan stands it
# px: the photographed border's signed distance is smoothed by a Gaussian this wide. A binary mask's border is a
# staircase, whose signed distance slopes along the edge as much as across it: a contour point sliding along
# the edge as the object turns then looks like a point moving across it, and the fit both stalled on the steps
# and believed itself 10–30× surer of a near-round object's tilt than it was (the ray-cast pebble: 0.4° off,
# ±0.03°); smoothed over a step, the slope is the edge's own (0.1° off, ±0.05°; docs/placement.md)
SDF_BLUR_PX = 1.0
# a contour point this near the photographed border was seen there (else: not lit, or not the object)
SEEN_PX = 3.0
# the border's bias as a function of its direction, to this harmonic (a pixel staircase's is the 4th)
BIAS_HARMONICS = 4
BIAS_FLOOR_PX = 0.02  # the least spread of its coefficients: ray-cast binary masks measured ~0.015 px
# the outline where the surface the camera sees faces further down than this (the z of its unit normal,
# turntable frame) is left out: every lamp is above the plate, so no lamp lights it head on, its shading
# fades toward the edge and the half-bright rule cuts the mask short there (bench register, at the truth:
# +0.2 to +0.6 px where the normal points down, ±0.1 px elsewhere), which lifted the fitted object
# (bunny and Spot 0.07 mm up, a region's n 4 % off end to end). Left out, with the 3 px half-bright window
# (photographs.py): the vertices' errors 0.074 → 0.035 mm RMS (bunny), 0.088 → 0.028 (Spot), 0.071 → 0.054
# (pebble); −0.5 or −0.15 instead did no better over the three. A box's bottom edge stays: the face the camera
# sees there is its side.
UNDERSIDE_NZ = -0.3
# the outline's RMS residual over its seen points: the right mesh gives 0.2–0.4 px (bench register; masks
# ray-cast from the mesh itself: 0.27 px); the lopsided test box 4 % longer and narrower 1.03 px, 6 % 1.25 px
# (tests/test_placement.py; a mesh merely too large is the outline's offset's to refuse): above this, the
# object is not the plan's mesh
EXPECTED_RESIDUAL_PX, MAX_RESIDUAL_PX = 0.6, 1.2
# the photographed outline's offset from the mesh's, all round (px, positive outside), fitted with the placement:
# the half-bright rule's edge lies a little outside or inside where the shading brightens or darkens toward
# the outline (bench register: +0.09 px on the painted bunny, −0.12 px on Spot, +0.03 px on the pebble), and
# a uniform offset left in the fit moves the object up or down (0.03 mm; the vertices' errors with it fitted:
# 0.035 → 0.023 mm RMS on the bunny, 0.028 → 0.020 on Spot at 200°, 12 mm, −8 mm). Beyond the largest, the
# object is larger or smaller than the mesh says: the lopsided test box 1 % larger than its mesh −0.47 px,
# 0.5 % −0.24 px (tests/test_placement.py)
EXPECTED_OFFSET_PX, MAX_OUTLINE_OFFSET_PX = 0.15, 0.35
# faces whose corners lie within this many pixels of each other are drawn at once (a scan's millions), the
# rest one by one by OpenCV (a call each): a scan's faces are under a pixel
_SMALL_FACE_PX = 1
_FACE_CHUNK = 1 << 20
_UNDER_A_PIXEL = 0.85  # px: a face this long at most spans neighbouring pixels (see Outlines._mask)
# a mesh whose median edge spans less than this in the image (a scan) is solved on a stand-in first, its vertices
# clustered on a grid of this cell (px at the object's distance), and only the last rounds on the mesh itself:
# at 3 px the stand-in's mask lies within a pixel of the scan's ray-cast one, inside the 1.5 px the outline is
# chosen within (the bunny split to 2.2 M vertices, docs/placement.md), and the rounds cost what a coarse
# mesh's do
STAND_IN_BELOW_PX, STAND_IN_CELL_PX = 1.0, 3.0
_EDGES_SIZED = 100_000  # faces whose edges' median length sizes a mesh (spread evenly over it)
MIN_SEEN = 0.8  # a placement whose outline is less than this share on the photographed one is no match
AMBIGUOUS_SE_DEG = 1.0  # a yaw less certain than this is not measured
# a candidate whose cost after two rounds is this many times the best's is refined no further: the rounds
# left lower a cost by far less (the pebble's: ≤ 1.02×), so it cannot come within AMBIGUOUS_RATIO
STILL_COMPETES = 3.0
AMBIGUOUS_RATIO = 1.2  # a second minimum this close to the best (cost ratio) and ≥ 20° away: not determined
COLOUR_PIXELS = 3000  # photographed pixels per view the colour step compares (drawn at random, seeded)
COLOUR_FLOOR_DEG = 0.1  # the colour turn's least stated error: bench register's cylinder, 0.07–0.10° off


@dataclass(frozen=True, eq=False)
class Registration:
    """Where the object was found: ``params`` (6,) of ``frame`` (rotation vector in degrees about the planned
    centre, then the shift in mm), their standard errors ``se`` (6,: of a further small turn about the
    turntable's x, y and z axes through the object's centre, degrees — the yaw is about z — then of the shift,
    mm), ``mesh_to_turntable`` (4, 4), the
    outline residual's RMS (px) over the ``points`` contour points found on the photographed outline
    (within :data:`SEEN_PX`), the share of the contour points so found (``outline_seen``), when a turn
    about the axis is not determined by the outlines, why (``ambiguous``), and the photographed outline's
    offset from the mesh's (``outline_offset_px``, px, positive outside: :data:`MAX_OUTLINE_OFFSET_PX`)."""

    params: np.ndarray
    se: np.ndarray
    mesh_to_turntable: np.ndarray
    residual_px: float
    points: int
    outline_seen: float
    ambiguous: str | None
    turn_from: str = "outlines"  # or "colours": what fixed the turn about the axis
    outline_offset_px: float = 0.0  # how far the photographed outline lay outside the mesh's, all round


def turn_angles(params: np.ndarray) -> tuple[float, float]:
    """The yaw about the vertical (−180° to 180°) and the tilt from it (degrees) of a placement's turn."""
    turn = Rotation.from_rotvec(np.radians(params[:3])).as_matrix()
    yaw = np.degrees(np.arctan2(turn[1, 0], turn[0, 0]))
    tilt = np.degrees(np.arccos(np.clip(turn[2, 2], -1.0, 1.0)))
    return float(yaw), float(tilt)


def view_camera(camera: Camera, turntable_deg: float) -> Camera:
    """The rig's camera (world) seen from the turntable at ``turntable_deg``, where the object sits still."""
    return camera.in_frame(rotation_z(np.radians(turntable_deg)))


class Outlines:
    """The mesh's outlines in the views, for placements of ``frame``. ``mesh`` in its own frame;
    ``camera`` the rig's (world); ``views`` the photographed masks."""

    def __init__(self, mesh: ColouredMesh, camera: Camera, frame: PlacementFrame, views: list[ObservedView]):
        if not views:
            raise PlacementError("registration needs at least one photographed view")
        self.mesh, self.frame, self.views = mesh, frame, views
        self.cameras = [view_camera(camera, v.turntable_deg) for v in views]
        # kept in float32 (5 MB a 1280 × 960 view); _sample reads it in float64
        self.sdf = [gaussian_filter(signed_distance(v.mask), SDF_BLUR_PX) for v in views]
        self._use(mesh)
        # the search's stand-in for the surface: points spread evenly over it (seeded: the same every run)
        self._samples = mesh.surface_samples(SEARCH_SAMPLES, seed=0)
        self._small = [_scaled(cam, 1 / SEARCH_SCALE) for cam in self.cameras]
        self._small_seen = [
            cv2.resize(v.mask.astype(np.float32), (c.width, c.height), interpolation=cv2.INTER_AREA) >= 0.5
            for v, c in zip(views, self._small, strict=True)
        ]

    def _use(self, mesh: ColouredMesh) -> None:
        """Take ``mesh`` (in its own frame) as the one whose outlines are drawn. The arrays every round reads
        are made when a round first needs them (:meth:`_build`): a scan's (~1 GB at 10 M vertices) need not
        exist while its stand-in is made and solved."""
        self.mesh = mesh
        self._built_for: ColouredMesh | None = None

    def _build(self) -> None:
        """The arrays every round reads, for ``self.mesh`` (once)."""
        mesh = self.mesh
        if self._built_for is mesh:
            return
        self._built_for = mesh
        # (E, 2) vertices of the edges two faces share, (E, 2) those faces; (R, 2) the edges of one face (an
        # open mesh's rims are outlines too), (R,) that face
        self._shared_edges, self._adjacent_faces, self._rim_edges, self._rim_faces = mesh.edge_faces()
        # (F,) each face's plane, n · x = offset (n its unit normal): a face turns toward an eye e when
        # n · e > offset. Kept instead of the faces' centroids, and the normals in float32 (the test is off only
        # for a face within ~1e-7 rad of edge-on): a scan's per-face arrays are its memory
        f = len(mesh.faces)
        self._normals = np.empty((f, 3), np.float32)  # (F, 3) unit, 0 for a degenerate face
        self._plane_offset = np.empty(f)
        self._normal_length = np.empty(f, np.float32)  # (F,) 1, or 0 degenerate
        self._face_size = np.empty(f, np.float32)  # (F,) m, the longest edge of each face
        for block in mesh.face_blocks():
            normals = mesh.face_normals_of(block)  # (B, 3)
            corners = mesh.vertices[mesh.faces[block]]  # (B, 3, 3)
            self._normals[block] = normals
            self._plane_offset[block] = np.einsum("ij,ij->i", normals, corners.mean(axis=1))
            self._normal_length[block] = lengths(normals)
            edges = corners - np.roll(corners, 1, axis=1)
            self._face_size[block] = np.sqrt((edges**2).sum(axis=2).max(axis=1))
        self._in_a_face = np.zeros(len(mesh.vertices), bool)  # (V,) a loaded mesh may carry stray vertices
        self._in_a_face[mesh.faces.ravel()] = True

    def stand_in(self) -> Outlines | None:
        """These outlines on a coarser copy of the mesh, for the search and the rounds that bring the placement
        near its end (:func:`register`), or None when the mesh's median edge spans :data:`STAND_IN_BELOW_PX`
        or more in the image. A scan's millions of vertices cost every round time in proportion to them, yet a
        copy whose vertices are the scan's clustered on a :data:`STAND_IN_CELL_PX` grid has an outline within
        a pixel of the scan's (docs/placement.md); the views, their masks and the search's surface samples are
        shared."""
        mesh = self.mesh
        cam = self.cameras[0]
        scale = float(np.cbrt(abs(np.linalg.det(self.frame.nominal[:3, :3]))))  # the plan's scale of the mesh
        px_per_m = (
            max(cam.matrix[0, 0], cam.matrix[1, 1]) * scale / np.linalg.norm(cam.centre - self.frame.centre)
        )
        # the edges of faces spread evenly over the mesh (each inner edge is two faces' edge: the lengths of
        # the edges themselves, alike)
        corners = mesh.vertices[mesh.faces[:: max(1, len(mesh.faces) // _EDGES_SIZED)]]  # (n, 3, 3)
        sides = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).ravel()  # (3n,)
        edge_px = np.median(sides) * px_per_m if len(sides) else np.inf
        if edge_px >= STAND_IN_BELOW_PX:
            return None
        normals = mesh.normals if mesh.normals is not None else mesh.area_weighted_normals()
        unlabelled = np.zeros(len(mesh.vertices), np.int8)
        clusters = cluster_vertices(
            mesh.vertices, normals, mesh.vertex_areas, unlabelled, STAND_IN_CELL_PX / px_per_m
        )
        coarse = copy.copy(self)
        coarse._use(clustered_mesh(mesh, clusters)[0])
        return coarse

    def contour_points(self, params: np.ndarray, drawn: Outlines | None = None) -> list[np.ndarray]:
        """Per view, the (N_k, 3) mesh-frame points along the contour edges on the outer outline: those within
        :data:`OUTLINE_PX` of the border of the mesh's predicted mask, or of ``drawn``'s (a stand-in's, whose
        border lies within a pixel of the mesh's: a scan's mask costs every face every round)."""
        drawn = drawn or self
        m = self.frame.matrix(params)
        inverse = np.linalg.inv(m)
        chosen = []
        self._build()
        lit = self._lit_faces(m)
        for cam in self.cameras:
            eye = (inverse[:3, :3] @ cam.centre + inverse[:3, 3]).astype(np.float32)  # camera, mesh frame
            toward = np.empty(len(self._normals), bool)  # (F,) a block at a time: a scan's temporaries
            for block in self.mesh.face_blocks():
                toward[block] = self._normals[block] @ eye > self._plane_offset[block]
            first, second = self._adjacent_faces[:, 0], self._adjacent_faces[:, 1]
            a, b = toward[first], toward[second]
            # the face of a contour edge that the camera sees must not face down (UNDERSIDE_NZ)
            contour = self._shared_edges[(a != b) & np.where(a, lit[first], lit[second])]
            rims = self._rim_edges[lit[self._rim_faces]]
            points = self._along(np.concatenate([contour, rims]), cam, m)
            pixels = self._project(cam, m, points)
            border = _border_distance(drawn._mask(cam, m))
            near = _sample(border, pixels) <= OUTLINE_PX
            chosen.append(points[near])
        return chosen

    def _lit_faces(self, m: np.ndarray) -> np.ndarray:
        """(F,) bool: the faces that do not face down, the mesh lying as ``m`` (4, 4) says (the underside,
        which no registration lamp lights head on, is left out: :data:`UNDERSIDE_NZ`)."""
        # m may scale (uniformly): the direction is what counts
        self._build()
        turned_z, least = m[2, :3].astype(np.float32), UNDERSIDE_NZ * np.linalg.norm(m[2, :3])
        lit = np.empty(len(self._normals), bool)
        for block in self.mesh.face_blocks():  # the turned normals' z, a block of faces at a time
            lit[block] = self._normals[block] @ turned_z >= least * self._normal_length[block]
        return lit

    def _along(self, edges: np.ndarray, cam: Camera, m: np.ndarray) -> np.ndarray:
        """(N, 3) mesh-frame points along ``edges`` (E, 2), about a pixel apart in ``cam``'s image (each
        edge's point centred in its share): a long straight edge of a coarse mesh is as many measurements
        as pixels it spans."""
        ends = self.mesh.vertices[edges]  # (E, 2, 3)
        pixels = self._project(cam, m, ends.reshape(-1, 3)).reshape(-1, 2, 2)
        length = np.nan_to_num(np.linalg.norm(pixels[:, 1] - pixels[:, 0], axis=1), nan=1.0)
        count = np.clip(np.ceil(length / POINT_SPACING_PX), 1, 4096).astype(np.int64)  # (E,)
        edge = np.repeat(np.arange(len(edges)), count)
        start = np.cumsum(count) - count
        t = ((np.arange(count.sum()) - start[edge]) + 0.5) / count[edge]  # (N,) in (0, 1)
        return ends[edge, 0] + t[:, None] * (ends[edge, 1] - ends[edge, 0])

    def residuals(self, params: np.ndarray, points: list[np.ndarray]) -> np.ndarray:
        """(ΣN_k,) px: each contour point's signed distance to its view's photographed border."""
        m = self.frame.matrix(params)
        return np.concatenate(
            [
                _sample(sdf, self._project(cam, m, p))
                for cam, sdf, p in zip(self.cameras, self.sdf, points, strict=True)
            ]
        )

    def border_angles(self, params: np.ndarray, points: list[np.ndarray]) -> np.ndarray:
        """(ΣN_k,) radians: the direction in the image (atan2 of y, x) of the photographed border's outward
        normal at each contour point, from the gradient of its view's signed distance."""
        m = self.frame.matrix(params)
        angles = []
        for cam, sdf, p in zip(self.cameras, self.sdf, points, strict=True):
            pixels = self._project(cam, m, p)
            across, down = (_sample(sdf, pixels + h) - _sample(sdf, pixels - h) for h in 0.5 * np.eye(2))
            angles.append(np.arctan2(down, across))
        return np.concatenate(angles)

    def overlap(self, params: np.ndarray) -> float:
        """The masks' mean intersection over union at 1/:data:`SEARCH_SCALE` resolution (0–1)."""
        m = self.frame.matrix(params)
        scores = []
        for small, seen in zip(self._small, self._small_seen, strict=True):
            predicted = self._splatted(small, m)
            scores.append(np.count_nonzero(predicted & seen) / max(np.count_nonzero(predicted | seen), 1))
        return float(np.mean(scores))

    def centre_shift(self, params: np.ndarray) -> np.ndarray:
        """(3,) mm: the shift that brings the predicted masks' centroids onto the photographed ones (a
        linearised least-squares step over the views, at the search's resolution)."""
        m = self.frame.matrix(params)
        centre = self.frame.centre + params[3:] / 1000
        steps = centre + np.vstack([np.zeros(3), 1e-3 * np.eye(3)])  # 1 mm along each axis
        rows, misses = [], []
        for small, seen in zip(self._small, self._small_seen, strict=True):
            predicted = self._splatted(small, m)
            if predicted.any() and seen.any():
                uv, _ = small.project(steps)
                rows.append((uv[1:] - uv[0]).T)  # (2, 3) px per mm
                misses.append(_centroid(seen) - _centroid(predicted))
        if not rows:
            return np.zeros(3)
        shift, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(misses), rcond=None)
        return shift

    def predicted_mask(self, k: int, m: np.ndarray) -> np.ndarray:
        """(H, W) bool: the object's image in view ``k`` lying as ``m`` (4, 4) mesh → turntable says."""
        return self._mask(self.cameras[k], m)

    def view_residuals_px(self, params: np.ndarray, offset_px: float = 0.0) -> list[float]:
        """Per view, the outline's RMS residual (px) at ``params`` over its contour points on the
        photographed outline (within :data:`SEEN_PX`), the outline's offset ``offset_px`` taken off; NaN
        for a view without any."""
        points = self.contour_points(params)
        residual = self.residuals(params, points) + offset_px
        out = []
        for part in np.split(residual, np.cumsum([len(p) for p in points])[:-1]):
            seen = part[np.abs(part) <= SEEN_PX]
            out.append(float(np.sqrt(np.mean(seen**2))) if len(seen) else float("nan"))
        return out

    def _splatted(self, cam: Camera, m: np.ndarray) -> np.ndarray:
        """(H, W) bool: the surface samples' pixels, closed over the gaps between them (the search's mask)."""
        uv, _ = cam.project(self._samples @ m[:3, :3].T + m[:3, 3])
        uv = uv[np.isfinite(uv).all(axis=1)]
        col, row = np.round(uv[:, 0]).astype(np.int64), np.round(uv[:, 1]).astype(np.int64)
        inside = (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
        mask = np.zeros((cam.height, cam.width), np.uint8)
        mask[row[inside], col[inside]] = 1
        return cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)) > 0

    def _mask(self, cam: Camera, m: np.ndarray) -> np.ndarray:
        """(H, W) bool: every face filled in — the object's image, also where an open mesh (a scan with holes
        in its base) shows its inside: each pixel whose centre a face covers, as a ray through it would hit
        the mesh (:func:`~hlr_lab.geometry.raster.fill_triangles`, all faces at once), and each vertex's pixel
        (the only pixels of a face whose corners lie within :data:`_SMALL_FACE_PX` of each other — a scan's
        faces — that are not looked at one by one), so the mask holds the ray-cast one and at most a pixel
        more along its border."""
        self._build()
        uv, depth = cam.project(self.mesh.vertices @ m[:3, :3].T + m[:3, 3])
        valid = np.asarray(np.isfinite(uv).all(axis=1) & (np.abs(uv) < 1e5).all(axis=1))  # (V,)
        fixed = np.zeros(uv.shape, np.int64)
        fixed[valid] = np.round(uv[valid] * ONE_PX)  # fixed point, as OpenCV's shift
        pixel = corner_pixels(fixed)  # (V, 2) the pixel each vertex lies in
        mask = np.zeros((cam.height, cam.width), np.uint8)
        _mark(mask, pixel[valid & self._in_a_face])  # every face's fill holds its corners' pixels
        # a face under a pixel across spans no more than neighbouring pixels: its corners' pixels are its fill.
        # Sized where the object is nearest the camera (m's scale included) and as far off the axis as it
        # reaches (a step of L at depth z and off-axis tangent t moves the image by at most L (1 + t) / z),
        # with a margin for the lens's distortion and the 1/16 px rounding; only larger faces are looked at
        nearest, off_axis = 1.0, 0.0
        if valid.any():
            nearest = max(float(depth[valid].min()), 1e-9)
            off_axis = float((np.abs(uv[valid] - cam.matrix[:2, 2]) / np.diag(cam.matrix)[:2]).max())
        focal = max(cam.matrix[0, 0], cam.matrix[1, 1])
        px_per_m = focal * np.linalg.norm(m[2, :3]) * (1 + off_axis) / nearest
        larger = np.flatnonzero(self._face_size * px_per_m >= _UNDER_A_PIXEL)
        for start in range(0, len(larger), _FACE_CHUNK):
            faces = self.mesh.faces[larger[start : start + _FACE_CHUNK]]
            ok = valid[faces[:, 0]] & valid[faces[:, 1]] & valid[faces[:, 2]]
            a, b, c = (pixel[faces[:, k]] for k in range(3))  # (B, 2) each corner's pixel
            spread = np.maximum(np.maximum(a, b), c) - np.minimum(np.minimum(a, b), c)
            small = (spread <= _SMALL_FACE_PX).all(axis=1)  # its corners, marked above, are its fill
            fill_triangles(mask, fixed[faces[ok & ~small]])
        return mask > 0

    @staticmethod
    def _project(cam: Camera, m: np.ndarray, points: np.ndarray) -> np.ndarray:
        uv, _ = cam.project(points @ m[:3, :3].T + m[:3, 3])
        return uv


def register(outlines: Outlines, *, yaw_step_deg: float = YAW_STEP_DEG) -> Registration:
    """Search every turn about the axis, refine the best few on the outlines, return the best.

    Raises :class:`PlacementError` when the best placement lies outside the search range
    (:data:`MAX_SHIFT_MM` off the axis, :data:`MAX_TILT_DEG` of tilt)."""
    solved = outlines.stand_in() or outlines  # a scan: its coarser stand-in until the last rounds
    scored = []
    for yaw in np.arange(0.0, 360.0, yaw_step_deg):
        params = yaw_params(float(yaw), np.zeros(3))
        for _ in range(2):  # the centroids' step is linearised: a second one lands within a pixel
            params = params + np.concatenate([np.zeros(3), outlines.centre_shift(params)])
        scored.append((outlines.overlap(params), params))
    scored.sort(key=lambda s: -s[0])
    starts: list[np.ndarray] = []
    for _, params in scored:  # the best overlaps, each at least two steps from those kept before it
        if all(_yaw_apart(params, kept) >= 2 * yaw_step_deg for kept in starts):
            starts.append(params)
        if len(starts) == CANDIDATES:
            break
    # two rounds of each, then to the end only those that could still compete (a wrong turn's fit wanders
    # for all its rounds: 60 % of the solve's time before this)
    fits = sorted((_refine(solved, params, rounds=2) for params in starts), key=lambda f: f[1])
    fits = [_refine(solved, f[0]) if k == 0 or _competes(f, fits[:k], yaw_step_deg) else f
            for k, f in enumerate(fits)]  # fmt: skip
    fits.sort(key=lambda f: f[1])
    best, cost, points = fits[0]
    if solved is not outlines:  # the last rounds on the mesh itself, from where its stand-in came to rest
        best, _, points = _refine(outlines, best, drawn=solved)
    ambiguous = None
    best_yaw = turn_angles(best)[0]
    for other, other_cost, _ in fits[1:]:
        other_yaw = turn_angles(other)[0]
        if _yaw_apart(other, best) >= 2 * yaw_step_deg and other_cost <= AMBIGUOUS_RATIO * cost:
            ambiguous = (
                f"the outlines fit as well turned {other_yaw:.1f}° as {best_yaw:.1f}° about the axis "
                f"(residual {np.sqrt(other_cost):.2f} against {np.sqrt(cost):.2f} px): the shape does not fix its turn"
            )
            break
    return _result(outlines, best, points, ambiguous)


def turn_by_colours(
    outlines: Outlines,
    found: Registration,
    regions: Callable[[PixelSurface], np.ndarray],
    expected: np.ndarray,
    *,
    pixels_per_view: int = COLOUR_PIXELS,
) -> Registration:
    """The turn about the vertical that the outlines left open, from the colour regions the mesh knows.

    Turned about the vertical through the found centre, the placement whose predicted regions best explain
    the photographed chromaticities wins: each pixel's chromaticity against its predicted region's
    ``expected`` one (R, 2), indexed by region id (the plan's palette, linear), through an affine map fitted
    per view (the lamp's and camera's colour cast; a permutation of the regions does not fit it), as the
    mean squared residual — every 2°, then every 0.1° within 2° of the best. Uniform regions alone would
    not do: a cylinder painted in four sectors looks uniform turned by any quarter. Each view is also
    scored alone; the yaw's standard error is the spread of the views' own best yaws over √views, at least
    :data:`COLOUR_FLOOR_DEG`. ``regions`` maps what the pixel rays hit (mesh frame) to region ids (−1 for
    none: ``formats.planned_object.surface_regions``). The views need ``chroma``
    (:func:`~hlr_lab.placement.photographs.observe`). Raises :class:`PlacementError` when the colours do
    not fix it either (a symmetric shape painted symmetrically).
    """
    rng = np.random.default_rng(0)
    caster = RayCaster(outlines.mesh)
    rays = []
    for cam, view in zip(outlines.cameras, outlines.views, strict=True):
        if view.chroma is None:
            raise PlacementError(f"the view at {view.turntable_deg:g}° has no colours measured")
        ys, xs = np.nonzero(np.isfinite(view.chroma).all(axis=2))
        pick = rng.choice(len(ys), size=min(pixels_per_view, len(ys)), replace=False)
        origins, dirs = cam.pixel_rays(np.stack([xs[pick], ys[pick]], axis=1).astype(np.float64))
        rays.append((origins, dirs, view.chroma[ys[pick], xs[pick]].astype(np.float64)))
    centre = outlines.frame.centre + found.params[3:] / 1000  # where the planned centre was found

    def misfits(yaw: float) -> np.ndarray:
        """(V,) each view's colour misfit (:func:`_colour_misfit`) for the placement turned by ``yaw``."""
        m = rotation_about_vertical(yaw, centre) @ found.mesh_to_turntable
        inverse = np.linalg.inv(m)
        out = np.empty(len(rays))
        for k, (origins, dirs, chroma) in enumerate(rays):
            d = dirs @ inverse[:3, :3].T
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            label = regions(caster.surface_along(origins @ inverse[:3, :3].T + inverse[:3, 3], d))
            out[k] = _colour_misfit(label, chroma, expected)
        return out

    coarse = np.arange(0.0, 360.0, 2.0)
    scores = np.array([misfits(y) for y in coarse])  # (Y, V)
    best = coarse[np.argmin(scores.sum(axis=1))]
    fine = best + np.arange(-2.0, 2.0 + 1e-9, 0.1)
    fine_scores = np.array([misfits(y) for y in fine])
    total = fine_scores.sum(axis=1)
    yaw = float(fine[np.argmin(total)])
    runner_up = scores.sum(axis=1)[np.abs((coarse - yaw + 180) % 360 - 180) > 20]
    if len(runner_up) and runner_up.min() <= AMBIGUOUS_RATIO**0.5 * total.min():
        raise PlacementError(
            "neither the outline nor the colours fix the object's turn about the axis (another turn fits "
            "the colours as well): mark the object, or place it as the plan says and record it as assumed"
        )
    per_view = fine[np.argmin(fine_scores, axis=0)]  # (V,) each view's own best
    # the views share their errors (the mask, the shading at the regions' borders), so their spread alone
    # understates: at least COLOUR_FLOOR_DEG, the rendered painted cylinder's measured error
    spread = float(np.std(per_view, ddof=1) / np.sqrt(len(per_view))) if len(per_view) > 1 else 0.0
    se_yaw = max(spread, COLOUR_FLOOR_DEG)
    m = rotation_about_vertical(yaw, centre) @ found.mesh_to_turntable
    se = found.se.copy()
    se[2] = se_yaw
    return replace(found, params=outlines.frame.params(m), se=se, mesh_to_turntable=m, ambiguous=None,
                   turn_from="colours")  # fmt: skip


def _mark(mask: np.ndarray, pixel: np.ndarray) -> None:
    """Set the pixels (N, 2) (column, row) of ``mask`` (H, W) that lie in it."""
    h, w = mask.shape
    inside = (pixel[:, 0] >= 0) & (pixel[:, 0] < w) & (pixel[:, 1] >= 0) & (pixel[:, 1] < h)
    mask[pixel[inside, 1], pixel[inside, 0]] = 1


def rotation_about_vertical(yaw_deg: float, centre: np.ndarray) -> np.ndarray:
    """(4, 4) a turn of ``yaw_deg`` about the vertical through ``centre`` (3,) (turntable frame, m)."""
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    turn[:3, 3] = centre - turn[:3, :3] @ centre
    return turn


def _colour_misfit(label: np.ndarray, chroma: np.ndarray, expected: np.ndarray) -> float:
    """The mean squared residual of the labelled pixels' chromaticity (N, 2) against an affine map of their
    regions' ``expected`` chromaticity (R, 2), fitted by least squares; ``label`` (N,) region ids, −1 none."""
    hit = label >= 0
    if hit.sum() < 10:
        return np.inf
    design = np.concatenate([expected[label[hit]], np.ones((int(hit.sum()), 1))], axis=1)  # (N, 3)
    fitted, *_ = np.linalg.lstsq(design, chroma[hit], rcond=None)
    return float(((chroma[hit] - design @ fitted) ** 2).sum() / hit.sum())


def _yaw_apart(a: np.ndarray, b: np.ndarray) -> float:
    """The difference (degrees, 0–180) between two placements' turns about the vertical."""
    return abs((turn_angles(a)[0] - turn_angles(b)[0] + 180) % 360 - 180)


def _competes(fit: tuple[np.ndarray, float, list[np.ndarray]], better: list, yaw_step_deg: float) -> bool:
    """Whether a candidate two rounds into its refinement could still be a second minimum of the outlines:
    not fallen onto a better one's turn, not leaning far beyond the search range, its cost not far above."""
    params, cost, _ = fit
    return (
        all(_yaw_apart(params, b[0]) >= 2 * yaw_step_deg for b in better)
        and turn_angles(params)[1] <= 2 * MAX_TILT_DEG
        and cost <= STILL_COMPETES * better[0][1]
    )


def _offset_residuals(x: np.ndarray, outlines: Outlines, points: list[np.ndarray]) -> np.ndarray:
    """(ΣN_k,) px: the outline residuals at the placement ``x[:6]`` with the photographed outline ``x[6]`` px
    outside the mesh's (a contour point lies that far inside the photographed border)."""
    return outlines.residuals(x[:6], points) + x[6]


def _refine(
    outlines: Outlines, start: np.ndarray, *, rounds: int = 8, drawn: Outlines | None = None
) -> tuple[np.ndarray, float, list[np.ndarray]]:
    """ICP on the outlines from ``start`` (6 or 7: a placement, with or without the outline's offset):
    choose the contour points (on ``drawn``'s masks' borders, if given: :meth:`Outlines.contour_points`),
    fit, until the placement stops moving (0.001° and 0.001 mm), at most ``rounds`` times. Returns the seven
    numbers, the mean robust cost per point and the last points."""
    x = start if len(start) == 7 else np.append(start, 0.0)
    points = outlines.contour_points(x[:6], drawn)
    cost = np.inf
    for _ in range(rounds):
        fit = least_squares(
            _offset_residuals, x, args=(outlines, points), loss="soft_l1", f_scale=ROBUST_PX, x_scale=1.0
        )
        moved = np.abs(fit.x - x).max()
        x = fit.x
        cost = 2 * fit.cost / max(len(fit.fun), 1)
        points = outlines.contour_points(x[:6], drawn)
        if moved < 1e-3:
            break
    return x, float(cost), points


def _result(
    outlines: Outlines, x: np.ndarray, points: list[np.ndarray], ambiguous: str | None
) -> Registration:
    """The registration at ``x`` (7: the placement's six numbers, the outline's offset), checked: refused
    when too little of the outline is found, the residual or the offset says another mesh or scale, or the
    placement lies outside the search range; its standard errors."""
    params, offset = x[:6], float(x[6])
    residual = _offset_residuals(x, outlines, points)
    seen = np.abs(residual) <= SEEN_PX
    if seen.mean() < MIN_SEEN:
        raise PlacementError(
            f"only {100 * seen.mean():.0f} % of the mesh's outline lies on the photographed one "
            f"(within {SEEN_PX:g} px; a match finds ≳ 95 %): is the object on the plate the plan's mesh, "
            "and is all of it lit and in view?"
        )
    rms = float(np.sqrt(np.mean(residual[seen] ** 2)))
    if rms > MAX_RESIDUAL_PX:
        raise PlacementError(
            f"the mesh's outline misses the photographed one by {rms:.2f} px RMS, where the right mesh in the "
            f"right place gives ≲ {EXPECTED_RESIDUAL_PX:g} px: is the object on the plate the plan's mesh (at "
            "the plan's scale)?"
        )
    if abs(offset) > MAX_OUTLINE_OFFSET_PX:
        raise PlacementError(
            f"the photographed outline lies {abs(offset):.2f} px {'outside' if offset > 0 else 'inside'} the mesh's "
            f"all round, where the right mesh gives ≲ {EXPECTED_OFFSET_PX:g} px: is the object on the plate the "
            "plan's mesh at the plan's scale, and the camera in focus?"
        )
    # how far from the axis the object's centre lies, against where the plan put it (an object whose vertices'
    # mean is off the axis moves it across the plate when it is merely turned: that is no distance)
    planned_mm = 1000 * float(np.hypot(*outlines.frame.centre[:2]))
    found_mm = 1000 * float(np.hypot(*(outlines.frame.centre[:2] + params[3:5] / 1000)))
    tilt = turn_angles(params)[1]
    if found_mm - planned_mm > MAX_SHIFT_MM or tilt > MAX_TILT_DEG:
        raise PlacementError(
            f"the object's centre lies {found_mm:.1f} mm from the turntable's axis (the plan's: {planned_mm:.1f} mm) "
            f"and it leans {tilt:.1f}° (the search covers {MAX_SHIFT_MM:.0f} mm further out and "
            f"{MAX_TILT_DEG:.0f}°): put it back near the turntable's centre, standing as the plan says, and "
            "register again"
        )
    # the standard errors (a jackknife of six refits) only for a placement that is kept, in the local
    # coordinates nudged() defines: a rotation vector's own components mean turns about the axes only near
    # zero, and a search may settle on one of ~345° as well as on its −15°
    step = 1e-3  # degrees, mm and px: central differences, far above the residuals' rounding
    jac = np.stack(
        [
            (
                _offset_residuals(_nudged(x, step * e), outlines, points)
                - _offset_residuals(_nudged(x, -step * e), outlines, points)
            )
            / (2 * step)
            for e in np.eye(7)
        ],
        axis=1,
    )[seen]  # (N_seen, 7) px per degree, per mm and per px of offset
    residual_seen = residual[seen]
    robust_sigma = 1.4826 * float(np.median(np.abs(residual_seen - np.median(residual_seen))))
    # neighbouring contour points read the same border pixels: count the outline's length in pixels, not
    # its points, as the independent measurements
    m = outlines.frame.matrix(params)
    independent = sum(
        len(np.unique(np.round(Outlines._project(cam, m, p)), axis=0))
        for cam, p in zip(outlines.cameras, points, strict=True)
    )
    inflate = max(1.0, len(residual_seen) / max(independent, 1))
    jtj = jac.T @ jac
    # a ridge far below any determined direction's curvature: a direction the outlines do not see (the turn
    # of a round object) gets a huge standard error instead of a singular matrix
    cov = np.linalg.inv(jtj + 1e-12 * np.trace(jtj) * np.eye(7)) * robust_sigma**2 * inflate
    statistical = np.maximum(np.sqrt(np.clip(np.diag(cov), 0, None)), _jackknife_se(outlines, x, points))
    bias = _outline_bias_se(jac, outlines.border_angles(params, points)[seen], residual_seen)
    se = np.hypot(statistical, bias)[:6]
    if ambiguous is None and se[2] > AMBIGUOUS_SE_DEG:
        ambiguous = (
            f"the outlines hardly change as the object turns about the axis (yaw ± {min(se[2], 999):.0f}°): "
            "a shape round about the vertical does not fix its turn"
        )
    return Registration(
        params=params,
        se=se,
        mesh_to_turntable=m,
        residual_px=rms,
        points=int(seen.sum()),
        outline_seen=float(seen.mean()),
        ambiguous=ambiguous,
        outline_offset_px=offset,
    )


def _jackknife_se(outlines: Outlines, x: np.ndarray, points: list[np.ndarray]) -> np.ndarray:
    """(7,) standard errors of ``x`` (the placement, the outline's offset; in :func:`_nudged`'s local
    coordinates) from the fits that leave one view out (the jackknife over views; zeros with fewer than three
    views). The outline's errors are not independent pixel to pixel — a mask's edge biased
    where the brightness changes fast, a straight edge quantised the same way along its length — so the
    Jacobian's errors alone came out 10–50× below the true errors (pebble: ±0.007° against 0.1–0.4°); how
    much the placement moves when a whole view is dropped measures what the views disagree on."""
    views = len(points)
    if views < 3:
        return np.zeros(len(x))
    estimates = []
    for left_out in range(views):
        kept = [p if k != left_out else p[:0] for k, p in enumerate(points)]
        fit = least_squares(_offset_residuals, x, args=(outlines, kept), loss="soft_l1", f_scale=ROBUST_PX)
        estimates.append(fit.x)
    local = np.array(
        [np.append(local_difference(e[:6], x[:6]), e[6] - x[6]) for e in estimates]
    )  # (views, 7)
    spread = local - local.mean(axis=0)
    return np.sqrt((views - 1) / views * (spread**2).sum(axis=0))


def _outline_bias_se(jac: np.ndarray, angles: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """(7,) what a bias of the photographed border that depends on its direction leaves uncertain in the fit's
    seven numbers (local coordinates), given its Jacobian ``jac`` (N, 7) at the contour points, their border's
    outward direction ``angles`` (N,) radians, and their residuals ``residual`` (N,) px.

    A mask's edge is not displaced at random from point to point: where the lamps light the outline from
    above, its top lies a little further out than its bottom (a vertical shift of the outline, which is a
    height), a binary mask's staircase sits differently on a diagonal than on a straight edge, and so on —
    one smooth function of the direction, the same in every view. The bias is modelled as its first
    :data:`BIAS_HARMONICS` harmonics in the direction, each coefficient of a spread σ_b; the numbers then move
    by G·c, G the least-squares map from a residual pattern to them, hence σ_b²·GGᵀ. σ_b is read from the fit's
    own residuals (the RMS of their harmonic coefficients; what the placement took up of the bias is not seen
    there, so it is a floor, never below :data:`BIAS_FLOOR_PX`). The rendered pebble measured 0.05–0.3 px of
    such bias at the true placement, the ray-cast masks ~0.02 px; without the term its height came out 3–5 SE
    off (docs/placement.md)."""
    order = np.arange(1, BIAS_HARMONICS + 1)
    basis = np.concatenate(
        [np.cos(np.outer(angles, order)), np.sin(np.outer(angles, order))], axis=1
    )  # (N, 2K)
    coefficients = np.linalg.lstsq(basis, residual - residual.mean(), rcond=None)[0]
    sigma_b = max(float(np.sqrt(np.mean(coefficients**2))), BIAS_FLOOR_PX)
    moves = np.linalg.lstsq(jac, basis, rcond=None)[0]  # (7, 2K)
    return sigma_b * np.sqrt((moves**2).sum(axis=1))


def _nudged(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(7,) :func:`~hlr_lab.placement.pose.nudged` of the placement ``x[:6]``, the outline's offset ``x[6]``
    moved by ``delta[6]``."""
    return np.append(nudged(x[:6], delta[:6]), x[6] + delta[6])


def _sample(image: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(N,) ``image`` (H, W) bilinear at ``pixels`` (N, 2) (x, y); far beyond the image where off it."""
    # interpolated in float64 whatever the image's type: the fit's finite differences move a point by ~1e-7 px,
    # below a float32 result's resolution, and a Jacobian of rounding noise stalls the fit short of the minimum
    values = map_coordinates(image, [pixels[:, 1], pixels[:, 0]], order=1, mode="nearest", output=np.float64)
    off = ~np.isfinite(pixels).all(axis=1)
    values[off] = 1e3
    return values


def _border_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float32: distance (px) of each pixel to the nearest pixel outside ``mask`` (0 outside)."""
    return cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def _centroid(mask: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean(), ys.mean()]) if len(xs) else np.zeros(2)


def _scaled(cam: Camera, factor: float) -> Camera:
    """The camera's image at ``factor`` of its resolution (pixel centres at integer coordinates kept)."""
    k = cam.matrix.copy()
    k[:2, :2] *= factor
    k[:2, 2] = (k[:2, 2] + 0.5) * factor - 0.5
    width, height = max(1, round(cam.width * factor)), max(1, round(cam.height * factor))
    return Camera(k, cam.distortion, cam.rotation, cam.translation, width, height)
