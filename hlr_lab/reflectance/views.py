"""One pose's pixels as fitting samples: what each pixel sees (ray cast from the calibrated camera at the
measured turntable angle), under which light (from the measured servo positions), and whether it can be
trusted.

Everything is computed in the turntable frame, where the mesh sits still. A pixel becomes a sample when
its radiance is usable (some unclipped frame), it sees the object, is lit (not in shadow, α below
``max_alpha_deg``), not seen grazing (view angle below ``max_view_deg``), and lies at least
``border_px`` pixels from a silhouette or a region border (mixed pixels there belong to neither side).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from hlr_lab.formats.plan import PlanFile
from hlr_lab.formats.planned_object import surface_regions
from hlr_lab.geometry.camera import Camera
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.object.mesh import CREASE_DEG, ColouredMesh
from hlr_lab.object.raycast import SURFACE_OFFSET, RayCaster
from hlr_lab.reflectance.hdr import Radiance


class StageTimes(dict):
    """Seconds per named stage, accumulated: ``with times("shadows"): …``."""

    @contextlib.contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self[stage] = self.get(stage, 0.0) + time.perf_counter() - t0


@dataclass(frozen=True)
class Selection:
    """Which pixels a fit may use: lit and seen within these angles (°), away from borders (px)."""

    max_alpha_deg: float = 80.0
    max_view_deg: float = 75.0
    border_px: int = 2


DEFAULT_SELECTION = Selection()


@dataclass(frozen=True, eq=False)
class PoseSamples:
    """N samples of one pose; arrays are (N, …)."""

    region: np.ndarray  # (N,) region id
    intensity: np.ndarray  # (N, C) linear radiance
    irradiance: np.ndarray  # (N,) Φ/d²
    cos_alpha: np.ndarray  # (N,)
    cos_beta: np.ndarray  # (N,) β between the normal and the half vector
    footprint: Footprint  # log cos β over each pixel's area
    pixel: np.ndarray  # (N, 2) int (x, y)
    point: np.ndarray  # (N, 3) what the pixel's centre ray meets, turntable frame (m)
    normal: np.ndarray  # (N, 3) the shading normal there
    black_slope: np.ndarray  # (N, C) how the intensity moves per DN of black level (Radiance.black_slope)

    def compact(self, which: np.ndarray) -> PoseSamples:
        """The samples ``which`` ((N,) bool), their floats as float32: what a session's fit keeps of a pose."""

        def f(a: np.ndarray) -> np.ndarray:
            return a[which].astype(np.float32)

        return PoseSamples(self.region[which], f(self.intensity), f(self.irradiance), f(self.cos_alpha),
                           f(self.cos_beta), Footprint(f(self.footprint.nodes)), self.pixel[which].astype(np.int32),
                           f(self.point), f(self.normal), f(self.black_slope))  # fmt: skip


@dataclass(frozen=True, eq=False)
class Footprint:
    """log cos β over each pixel's area: its values (N, 4) at the four two-point Gauss–Legendre nodes of the
    pixel's box (``_FOOTPRINT_NODES``; the centre ray's value four times where one ray serves). A pixel
    integrates the surface over its box, whose normal turns on a curved object (~1.5° across a pixel on the
    bunny's ears): the lobe it records is the mean of cosⁿβ over the box, lower and wider than the centre
    ray's cosⁿβ, so a fit at the centre gives n and Rs low (docs/fitting.md, "The pixel's footprint")."""

    nodes: np.ndarray  # (N, 4) log cos β

    @classmethod
    def at_centre(cls, cos_beta: np.ndarray) -> Footprint:
        """Point samples: every node the centre ray's cos β (N,) (0 and below: the floor, a lobe of 0)."""
        with np.errstate(divide="ignore"):
            centre = np.maximum(np.log(cos_beta), _LOG_COS_FLOOR)
        return cls(np.repeat(centre[:, None], len(_FOOTPRINT_NODES), axis=1))

    def __getitem__(self, which: np.ndarray) -> Footprint:
        return Footprint(self.nodes[which])


# two-point Gauss–Legendre nodes per axis: the mean over the pixel's box of anything cubic across it is
# exact from these four rays
_FOOTPRINT_NODES = np.array([[-1, -1], [-1, 1], [1, -1], [1, 1]]) / (2 * np.sqrt(3))
FOOTPRINT_BETA_DEG = 40.0  # beyond this β no lobe worth fitting changes over a pixel: the centre ray serves
_LOG_COS_FLOOR = np.log(1e-6)  # a sub-ray past 90° (the half vector below the surface): the lobe is 0 there


@dataclass(frozen=True)
class PoseGeometry:
    """A pose's light as measured: turntable angle (°), the lamp's position (m) and power."""

    turntable_deg: float
    light_world: np.ndarray  # (3,) the lamp where the servos measured it, world frame
    power: float  # Φ
    # a distant lamp: light travels from the lamp toward the gantry centre, irradiance Φ everywhere
    directional_from: np.ndarray | None = None  # (3,) the gantry centre (world) for a directional light


@dataclass(frozen=True, eq=False)
class PixelGeometry:
    """Every pixel of a pose where the object is seen; arrays are (N, …)."""

    pixel: np.ndarray  # (N, 2) int (x, y)
    region: np.ndarray  # (N,) region id
    point: np.ndarray  # (N, 3) turntable frame (m)
    normal: np.ndarray  # (N, 3) shading normal
    irradiance: np.ndarray  # (N,) Φ/d²
    cos_alpha: np.ndarray  # (N,) may be ≤ 0: facing away from the lamp
    cos_view: np.ndarray  # (N,)
    cos_beta: np.ndarray  # (N,) β between the normal and the half vector
    lit: np.ndarray  # (N,) bool: faces the lamp and nothing lies between
    labels: np.ndarray  # (H, W) region id per pixel, −1 off the object
    normals: np.ndarray  # (H, W, 3) shading normal per pixel, NaN off the object
    cast_shadow: np.ndarray  # (H, W) bool: faces the lamp, but something lies between

    def interior(self, border_px: int) -> np.ndarray:
        """(N,) bool: at least ``border_px`` pixels from a silhouette, a region border, a crease or a cast
        shadow, where a pixel mixes surfaces (or light and shadow) that the pixel-centre geometry does not
        describe."""
        x, y = self.pixel[:, 0], self.pixel[:, 1]
        near = _near_crease(self.normals, border_px) | _dilated(self.cast_shadow, border_px)
        return _interior(self.labels, border_px)[y, x] & ~near[y, x]


def pose_geometry(
    plan: PlanFile,
    mesh: ColouredMesh,
    caster: RayCaster,
    camera: Camera,
    pose: PoseGeometry,
    within: np.ndarray,
    timer: StageTimes | None = None,
) -> PixelGeometry:
    """What each pixel sees at this pose, under which light. ``within``: (H, W) bool, the pixels to
    consider: those with usable radiance (``session_fit.view_radiance`` limits them to the object's window).

    mesh and caster: the object in the turntable frame; camera: the rig's calibrated camera (world).
    timer: adds the seconds of the "g-buffer" and "shadows" stages.
    """
    timer = timer if timer is not None else StageTimes()
    cam, light, directional = pose_frame(camera, pose)
    with timer("g-buffer"):
        ys, xs = np.nonzero(within)
        surface = caster.surface(cam, np.stack([xs, ys], axis=1).astype(np.float64))
        labels = np.full((camera.height, camera.width), -1, np.int64)
        labels[ys, xs] = surface_regions(plan, mesh, surface)
    hit = surface.hit
    point, normal = surface.point[hit], surface.normal[hit]
    l_dir, v_dir, irradiance, cos_beta = _towards(point, normal, light, cam.centre, directional, pose.power)
    cos_alpha = np.einsum("ij,ij->i", normal, l_dir)
    lit = cos_alpha > 0
    with timer("shadows"):
        if pose.directional_from is None:
            lit[lit] = ~caster.shadowed(point[lit], normal[lit], light)
        else:  # toward a point far beyond the object along the light
            far = point[lit] + l_dir[lit] * (100 * caster.scale)
            lit[lit] = ~caster.segment_blocked(
                point[lit] + normal[lit] * (SURFACE_OFFSET * caster.scale), far
            )
    cast_shadow = np.zeros(labels.shape, bool)
    cast_shadow[ys[hit], xs[hit]] = (cos_alpha > 0) & ~lit
    return PixelGeometry(
        pixel=np.stack([xs[hit], ys[hit]], axis=1),
        region=labels[ys[hit], xs[hit]],
        point=point,
        normal=normal,
        irradiance=irradiance,
        cos_alpha=cos_alpha,
        cos_view=np.einsum("ij,ij->i", normal, v_dir),
        cos_beta=cos_beta,
        lit=lit,
        labels=labels,
        normals=_normal_image(labels.shape, xs[hit], ys[hit], normal),
        cast_shadow=cast_shadow,
    )


@dataclass(frozen=True, eq=False)
class LightTerms:
    """What the fit reads of N samples' geometry: irradiance Φ/d², cos α, cos β (N,) and log cos β at the
    footprint's nodes (N, 4)."""

    irradiance: np.ndarray
    cos_alpha: np.ndarray
    cos_beta: np.ndarray
    footprint: np.ndarray


def light_terms_again(
    caster: RayCaster,
    camera: Camera,
    pose: PoseGeometry,
    samples: PoseSamples,
    *,
    recast: bool,
    object_moved: np.ndarray | None = None,
) -> LightTerms:
    """The light terms of ``samples`` (one pose's, the same pixels) under ``camera`` and ``pose`` — a rig
    believed a little differently (docs/fitting.md, "Systematic uncertainty"); ``object_moved`` (4, 4): the
    object lying moved by this rigid move of the turntable frame from where the plan places it. ``recast``:
    the camera or the object moved, so each pixel's centre ray is cast again (a pixel whose ray now misses
    keeps its old point); otherwise the samples' points and normals serve. The footprint's nodes move as the
    centre's log cos β does (the rig's small moves turn the whole pixel's lobe alike)."""
    cam, light, directional = pose_frame(camera, pose, object_moved)
    point, normal = samples.point.astype(np.float64), samples.normal.astype(np.float64)
    if recast and len(point):
        surface = caster.surface(cam, samples.pixel.astype(np.float64))
        point = np.where(surface.hit[:, None], surface.point, point)
        normal = np.where(surface.hit[:, None], surface.normal, normal)
    l_dir, _, irradiance, cos_beta = _towards(point, normal, light, cam.centre, directional, pose.power)
    cos_alpha = np.einsum("ij,ij->i", normal, l_dir)
    with np.errstate(divide="ignore"):
        moved = np.maximum(np.log(cos_beta), _LOG_COS_FLOOR) - np.maximum(
            np.log(samples.cos_beta), _LOG_COS_FLOOR
        )
    nodes = np.clip(samples.footprint.nodes + moved[:, None], _LOG_COS_FLOOR, 0.0)
    return LightTerms(irradiance, cos_alpha, cos_beta, nodes)


def _towards(points, normals, light, camera_centre, directional, power):
    """Unit directions to the lamp and to the camera (N, 3), the irradiance (N,) and cos β (N,) at surface
    ``points`` (N, 3) with ``normals``; ``directional``: the light's direction of travel reversed (a
    distant lamp), or None for the point lamp at ``light`` (3,)."""
    if directional is None:
        to_light = light - points
        d2 = np.einsum("ij,ij->i", to_light, to_light)
        l_dir = to_light / np.sqrt(d2)[:, None]
        irradiance = power / d2
    else:
        l_dir = np.broadcast_to(directional / np.linalg.norm(directional), points.shape)
        irradiance = np.full(len(points), power)
    v_dir = camera_centre - points
    v_dir /= np.linalg.norm(v_dir, axis=1, keepdims=True)
    half = l_dir + v_dir
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    return l_dir, v_dir, irradiance, np.clip(np.einsum("ij,ij->i", normals, half), 0.0, 1.0)


def pose_frame(
    camera: Camera, pose: PoseGeometry, object_moved: np.ndarray | None = None
) -> tuple[Camera, np.ndarray, np.ndarray | None]:
    """The pose seen from the turntable, where the mesh sits still: the camera, the lamp's position (3,)
    and, for a distant lamp, the direction toward it (3,; None for a point lamp). ``object_moved`` (4, 4),
    a rigid move of the turntable frame: the object lies so moved from where the plan places it, which,
    seen from the object, is the camera and the lamp moved back."""
    world_from_tt = rotation_z(np.radians(pose.turntable_deg))
    if object_moved is not None:
        world_from_tt = world_from_tt @ object_moved
    to_tt = world_from_tt[:3, :3].T  # world → turntable (a rotation)
    light = to_tt @ (pose.light_world - world_from_tt[:3, 3])
    directional = (
        None if pose.directional_from is None else to_tt @ (pose.light_world - pose.directional_from)
    )
    return camera.in_frame(world_from_tt), light, directional


def pixel_footprint(
    caster: RayCaster, camera: Camera, pose: PoseGeometry, pixel: np.ndarray, cos_beta: np.ndarray
) -> Footprint:
    """log cos β at the four nodes of each of the lit ``pixel`` (N, 2) boxes (``_FOOTPRINT_NODES``) for those
    within ``FOOTPRINT_BETA_DEG`` of a highlight (``cos_beta`` (N,), the centre ray's); elsewhere the
    centre ray's value. A pixel whose rays do not all meet the surface (a silhouette runs through it) keeps
    its centre ray too."""
    cam, light, directional = pose_frame(camera, pose)
    nodes = Footprint.at_centre(cos_beta).nodes
    near = np.flatnonzero(cos_beta >= np.cos(np.radians(FOOTPRINT_BETA_DEG)))
    if len(near) == 0:
        return Footprint(nodes)
    values, whole = np.empty((len(near), len(_FOOTPRINT_NODES))), np.ones(len(near), bool)
    for k, offset in enumerate(_FOOTPRINT_NODES):
        sub = caster.surface(cam, pixel[near] + offset)
        whole &= sub.hit
        point = np.where(sub.hit[:, None], sub.point, 0.0)
        normal = np.where(sub.hit[:, None], sub.normal, [0.0, 0.0, 1.0])
        cb = _towards(point, normal, light, cam.centre, directional, pose.power)[3]
        with np.errstate(divide="ignore"):
            values[:, k] = np.maximum(np.log(cb), _LOG_COS_FLOOR)
    nodes[near[whole]] = values[whole]
    return Footprint(nodes)


def selected(g: PixelGeometry, selection: Selection = DEFAULT_SELECTION) -> np.ndarray:
    """(N,) bool: the pixels of ``g`` a fit may use — lit, not grazing in light or view, away from borders."""
    return (
        g.lit
        & g.interior(selection.border_px)
        & (g.cos_alpha >= np.cos(np.radians(selection.max_alpha_deg)))
        & (g.cos_view >= np.cos(np.radians(selection.max_view_deg)))
    )


def pose_samples(
    plan: PlanFile,
    mesh: ColouredMesh,
    caster: RayCaster,
    camera: Camera,
    pose: PoseGeometry,
    radiance: Radiance,
    selection: Selection = DEFAULT_SELECTION,
    timer: StageTimes | None = None,
    geometry: PixelGeometry | None = None,
) -> PoseSamples:
    """The pose's samples: lit, visible, not grazing, usable radiance, away from borders.

    timer: adds the seconds of the "g-buffer", "shadows", "footprint" and "selection" stages.
    geometry: the pose's :func:`pose_geometry`, when the caller has it already.
    """
    timer = timer if timer is not None else StageTimes()
    g = geometry or pose_geometry(plan, mesh, caster, camera, pose, radiance.usable, timer)
    with timer("selection"):
        keep = selected(g, selection)
        pixel = g.pixel[keep]
    with timer("footprint"):  # only for the samples kept: the rays are the stage's cost
        footprint = pixel_footprint(caster, camera, pose, pixel.astype(np.float64), g.cos_beta[keep])
    intensity = radiance.value[pixel[:, 1], pixel[:, 0]].astype(np.float64)
    return PoseSamples(
        region=g.region[keep],
        intensity=intensity,
        irradiance=g.irradiance[keep],
        cos_alpha=g.cos_alpha[keep],
        cos_beta=g.cos_beta[keep],
        footprint=footprint,
        pixel=pixel,
        point=g.point[keep],
        normal=g.normal[keep],
        black_slope=(
            np.zeros_like(intensity)
            if radiance.black_slope is None
            else radiance.black_slope[pixel[:, 1], pixel[:, 0]].astype(np.float64)
        ),
    )


def _normal_image(shape: tuple[int, int], xs: np.ndarray, ys: np.ndarray, normal: np.ndarray) -> np.ndarray:
    image = np.full((*shape, 3), np.nan, np.float32)
    image[ys, xs] = normal
    return image


def _near_crease(normals: np.ndarray, border_px: int) -> np.ndarray:
    """(H, W) bool: within ``border_px`` of two neighbouring pixels whose normals differ by more than
    ``CREASE_DEG`` / 2 (a sharp edge crosses between them)."""
    limit = np.cos(np.radians(CREASE_DEG / 2))
    edge = np.zeros(normals.shape[:2], np.uint8)
    with np.errstate(invalid="ignore"):
        across = (normals[:, 1:] * normals[:, :-1]).sum(axis=-1) < limit  # NaN (off the object): no edge
        down = (normals[1:] * normals[:-1]).sum(axis=-1) < limit
    edge[:, 1:] |= across
    edge[:, :-1] |= across
    edge[1:] |= down
    edge[:-1] |= down
    return _dilated(edge, border_px)


def _dilated(mask: np.ndarray, border_px: int) -> np.ndarray:
    """(H, W) bool: within ``border_px`` (a square) of a pixel of ``mask`` (H, W)."""
    if border_px <= 0:
        return mask.astype(bool)
    kernel = np.ones((2 * border_px + 1, 2 * border_px + 1), np.uint8)
    return cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)


def _interior(labels: np.ndarray, border_px: int) -> np.ndarray:
    """(H, W) bool: every pixel within ``border_px`` has the same label (off-object counts as a label)."""
    if border_px <= 0:
        return np.ones(labels.shape, bool)
    kernel = np.ones((2 * border_px + 1, 2 * border_px + 1), np.uint8)
    f = labels.astype(np.float32)  # region ids are small integers: exact in float32
    return cv2.erode(f, kernel) == cv2.dilate(f, kernel)
