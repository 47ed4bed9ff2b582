"""``hlr-lab bench image-formation``: how far the fit's picture of a pixel (one ray through its centre) is
from how the simulated camera forms it, and what that costs in n and Rs (issue 21, §1).

The simulated camera renders on its own pixel grid, each pixel box-filtered (Mitsuba's ``box``
reconstruction filter, rays undistorted where they leave the camera: :mod:`sim.render.opencv_sensor`), as
a real sensor's pixel integrates the light over its square. A pixel's value is therefore the mean of the
surface's radiance over a patch whose normal varies on a curved object, while one ray evaluates the
model once, at the centre.
A lobe averaged over varying normals is lower and wider than the lobe at the mean normal: n and Rs come
out low, more so for sharp lobes and curved surfaces.

For a session of the default simulated world (the plan's mesh, each planned region with the world's
default material: the truth is known), every pixel the fit would use is compared against three
predictions of the true model: at the pixel centre, and averaged over the pixel's box (K × K rays).
Each prediction is also fitted, noise-free, with the centre-ray geometry the fit uses: the n and Rs it
gives are what that part of image formation alone does to the fit.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hlr_lab.fitting import fit_region
from hlr_lab.formats.planned_object import region_ids
from hlr_lab.object.raycast import RayCaster
from hlr_lab.reflectance.session_fit import Session, open_session, placed_mesh, view_pose, view_radiance
from hlr_lab.reflectance.views import pixel_footprint, pose_frame, pose_geometry, selected
from sim.render.scene import Material
from worlds.plan_world import sim_scene

MODELS = ("centre ray", "pixel box")  # the predictions, in the order of their columns
BETA_BINS_DEG = (0, 2, 4, 6, 8, 10, 14, 20, 30, 90)


@dataclass(frozen=True)
class RegionFigures:
    """One region: its true n and grey Rs, and (n, grey Rs) fitted to the data (at the pixel centres, and
    with the pixel's footprint modelled as ``hlr-lab fit`` does) and to each prediction."""

    region: int
    truth: tuple[float, float]
    data: tuple[float, float]  # fitted at the pixel centres
    worlds: tuple[tuple[float, float], ...]  # one per MODELS entry
    footprint: tuple[float, float]  # the data fitted as ``hlr-lab fit`` does: each pixel's box modelled


@dataclass(frozen=True)
class ImageFormation:
    """Residuals (data − prediction) / prediction in % per β bin (rows: BETA_BINS_DEG[i]…[i + 1]; columns:
    MODELS), the samples per bin, and the per-region fits."""

    residual_pct: np.ndarray  # (B, 3)
    samples: np.ndarray  # (B,)
    regions: list[RegionFigures]


def image_formation(session_path: Path, sub: int = 3) -> ImageFormation:
    """Compare ``session_path``'s pixels (a session of the default simulated world, acquired on the nominal
    rig) with the true model under each model of image formation (MODELS); ``sub``: rays per pixel side."""
    s = open_session(session_path)
    scene = sim_scene(s.plan, s.plan_path, None)
    truth = dict(zip(region_ids(s.plan).tolist(), scene.materials, strict=True))
    mesh = placed_mesh(s)
    caster = RayCaster(mesh)
    parts = [_view_samples(s, view, caster, mesh, truth, sub) for view in s.views]
    cb, data, irradiance, cos_alpha, region, nodes, *predictions = (
        np.concatenate(p) for p in zip(*parts, strict=True)
    )
    ok = np.all([np.isfinite(p).all(axis=1) for p in predictions], axis=0)
    beta = np.degrees(np.arccos(cb))
    edges = np.asarray(BETA_BINS_DEG)
    which = np.digitize(beta, edges) - 1
    residual = np.full((len(edges) - 1, len(MODELS)), np.nan)
    counts = np.zeros(len(edges) - 1, np.int64)
    for b in range(len(edges) - 1):
        m = ok & (which == b)
        counts[b] = m.sum()
        for k, p in enumerate(predictions):
            if m.any():
                residual[b, k] = 100 * (data[m].sum() - p[m].sum()) / p[m].sum()
    regions = []
    for r in sorted(set(region.tolist())):
        m = ok & (region == r)
        fits = [
            fit_region(y[m], irradiance[m], cos_alpha[m], cb[m], theta_c_deg="auto")
            for y in (data, *predictions)
        ]
        fits.append(
            fit_region(data[m], irradiance[m], cos_alpha[m], cb[m], theta_c_deg="auto", footprint=nodes[m])
        )
        pairs = tuple((float(f.n), float(np.mean(f.rs))) for f in fits)
        truths = (truth[r].n, float(np.mean(truth[r].rs)))
        regions.append(RegionFigures(r, truths, pairs[0], pairs[1:-1], pairs[-1]))
    return ImageFormation(residual, counts, regions)


def _view_samples(s: Session, view, caster: RayCaster, mesh, truth: dict[int, Material], sub: int):
    """One view's samples as the fit selects them: cos β, data (N, 3), irradiance, cos α, region, the
    footprint's log cos β (N, 4), and the predictions (N, 3) each, in MODELS' order."""
    radiance = view_radiance(s, view, mesh)
    pose = view_pose(s, view)
    camera = s.rig.camera
    g = pose_geometry(s.plan, mesh, caster, camera, pose, radiance.usable)
    keep = selected(g)
    pixels, region = g.pixel[keep].astype(np.float64), g.region[keep]
    cam, light, _ = pose_frame(camera, pose)  # the default world's lamp is a point
    rd, rs = (np.array([getattr(truth[int(r)], k) for r in region]) for k in ("rd", "rs"))
    n = np.array([truth[int(r)].n for r in region])

    def predict(at: np.ndarray) -> np.ndarray:  # the true model along the rays through ``at`` (N, 2)
        surface = caster.surface(cam, at)
        to_light = light - surface.point
        d2 = np.einsum("ij,ij->i", to_light, to_light)
        l_dir = to_light / np.sqrt(d2)[:, None]
        v_dir = cam.centre - surface.point
        v_dir /= np.linalg.norm(v_dir, axis=1, keepdims=True)
        half = (l_dir + v_dir) / np.linalg.norm(l_dir + v_dir, axis=1, keepdims=True)
        ca = np.clip(np.einsum("ij,ij->i", surface.normal, l_dir), 0, None)
        cb = np.clip(np.einsum("ij,ij->i", surface.normal, half), 0, 1)
        value = pose.power / d2[:, None] * (rd * ca[:, None] + rs * (cb**n)[:, None])
        return np.where(surface.hit[:, None], value, np.nan)

    offsets = (np.arange(sub) + 0.5) / sub - 0.5
    grid = [np.array([dx, dy]) for dx in offsets for dy in offsets]
    centre = predict(pixels)
    box = np.mean([predict(pixels + d) for d in grid], axis=0)
    data = radiance.value[g.pixel[keep, 1], g.pixel[keep, 0]].astype(np.float64)
    nodes = pixel_footprint(caster, camera, pose, pixels, g.cos_beta[keep]).nodes  # as hlr-lab fit casts them
    return g.cos_beta[keep], data, g.irradiance[keep], g.cos_alpha[keep], region, nodes, centre, box


def image_formation_lines(result: ImageFormation) -> list[str]:
    """The residual table and the per-region fits, for the console."""
    lines = ["data against the true model, (data − prediction) / prediction, % (grey):",
             f"{'β (°)':>9} {'pixels':>8} " + " ".join(f"{m:>12}" for m in MODELS)]  # fmt: skip
    for b, count in enumerate(result.samples):
        cells = " ".join(f"{v:+12.3f}" for v in result.residual_pct[b])
        lines.append(f"{BETA_BINS_DEG[b]:>4}–{BETA_BINS_DEG[b + 1]:<4} {count:8d} {cells}")
    lines += ["", "n and grey Rs fitted with the centre-ray geometry (noise-free predictions: the effect alone); "
              "last, the data as hlr-lab fit fits them (each pixel's box modelled):",
              f"{'region':>6} {'truth':>14} {'data':>14} " + " ".join(f"{m:>14}" for m in MODELS)
              + f" {'data, box fit':>14}"]  # fmt: skip
    for r in result.regions:
        cells = " ".join(
            f"{n:7.2f} {rs:.4f}"[:14].rjust(14) for n, rs in (r.truth, r.data, *r.worlds, r.footprint)
        )
        lines.append(f"{r.region:>6} {cells}")
    return lines
