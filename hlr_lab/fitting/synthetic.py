"""Seeded synthetic regions with a known truth: the ground truth the estimators are measured against.

Analytic shapes (sphere, cylinder, torus) seen by a perspective camera, lit by a directional light or a
point light with 1/d² fall-off; intensities from eq. (1), then a sensor: Gaussian read noise, photon
(Poisson) noise, quantisation to 8/12/16 bits, and saturated pixels dropped — as the pipeline never
uses a clipped value. Convex shapes cast no shadows; the torus's self-shadowing is ignored (the values
still follow eq. (1) exactly, which is all an estimator test needs).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Shape = Literal["sphere", "cylinder", "torus"]


@dataclass(frozen=True)
class Truth:
    """A known material: Rd, Rs (3,) linear, and the exponent n."""

    rd: np.ndarray
    rs: np.ndarray
    n: float


PAPER_42 = Truth(np.array([230, 223, 205]) / 255, np.array([27, 18, 28]) / 255, 59.0)


@dataclass(frozen=True, eq=False)
class SyntheticRegion:
    """Pixels of one region rendered from a known :class:`Truth` with sensor noise, as a fit receives them."""

    intensity: np.ndarray  # (N, 3) linear, as the fit sees it
    irradiance: np.ndarray  # (N,)
    cos_alpha: np.ndarray
    cos_beta: np.ndarray
    truth: Truth
    clipped: int  # saturated pixels dropped


def synthetic_region(
    truth: Truth,
    *,
    shape: Shape = "cylinder",
    light: Literal["directional", "point"] = "directional",
    pixels: int = 40_000,
    bits: int = 8,
    read_noise_dn: float = 1.0,
    electrons_per_dn: float | None = None,
    full_scale: float = 1.0,
    seed: int = 0,
) -> SyntheticRegion:
    """``full_scale`` is the intensity that reads the sensor's top code; ``electrons_per_dn`` turns on
    photon noise (None: none). Generated in batches, so ten million pixels need little more than the
    output's own memory."""
    rng = np.random.default_rng(seed)
    geometry = _Geometry(shape, light)
    parts, total, clipped = [], 0, 0
    while total < pixels:
        batch = _batch(
            truth,
            geometry,
            rng,
            min(pixels - total, _BATCH),
            bits,
            read_noise_dn,
            electrons_per_dn,
            full_scale,
        )
        parts.append(batch[:4])
        clipped += batch[4]
        total += len(batch[3])
    columns = [np.concatenate(c) for c in zip(*parts, strict=True)]
    return SyntheticRegion(*(c[:pixels] for c in columns), truth=truth, clipped=clipped)


_BATCH = 1 << 20


@dataclass(frozen=True)
class _Geometry:
    shape: Shape
    light: str

    @property
    def camera(self) -> np.ndarray:
        return np.array([0.0, -0.6, 0.0]) if self.shape == "cylinder" else np.array([0.0, -0.6, 0.18])

    @property
    def light_dir(self) -> np.ndarray:
        return _unit(np.array([0.35, -1.0, 0.0 if self.shape == "cylinder" else 0.45]))


def _batch(truth, g: _Geometry, rng, want, bits, read_noise_dn, electrons_per_dn, full_scale):
    p, nrm = _surface(g.shape, rng, 3 * want)
    v = _unit(g.camera - p)
    if g.light == "directional":
        to_light, irr = np.broadcast_to(g.light_dir, p.shape), np.ones(len(p))
    else:
        d = 0.25 * g.light_dir - p
        to_light, irr = _unit(d), 0.0625 / np.einsum("ij,ij->i", d, d)  # Φ = 0.0625 reads 1 at 0.25 m
    ca = np.einsum("ij,ij->i", nrm, to_light)
    front = (np.einsum("ij,ij->i", nrm, v) > 0.05) & (ca > 0.05)
    nrm, v, to_light, irr, ca = nrm[front], v[front], to_light[front], irr[front], ca[front]
    cb = np.clip(np.einsum("ij,ij->i", nrm, _unit(to_light + v)), 1e-9, 1.0)
    clean = irr[:, None] * (ca[:, None] * truth.rd + cb[:, None] ** truth.n * truth.rs)
    top = 2**bits - 1
    dn = clean / full_scale * top
    if electrons_per_dn:
        dn = rng.poisson(dn * electrons_per_dn) / electrons_per_dn
    dn = np.round(dn + rng.normal(0.0, read_noise_dn, dn.shape))
    ok = (dn < top).all(axis=1)
    measured = np.clip(dn[ok], 0, None) / top * full_scale
    return measured, irr[ok], ca[ok], cb[ok], int((~ok).sum())


def _surface(shape: Shape, rng: np.random.Generator, k: int) -> tuple[np.ndarray, np.ndarray]:
    if shape == "sphere":
        nrm = _unit(rng.normal(size=(k, 3)))
        return 0.05 * nrm, nrm
    if shape == "cylinder":
        phi, z = rng.uniform(0, 2 * np.pi, k), rng.uniform(-0.05, 0.05, k)
        nrm = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(k)])
        return 0.05 * nrm + np.column_stack([np.zeros((k, 2)), z]), nrm
    # torus, major radius R, minor r; area density ∝ R + r cos v (rejection sampling keeps it uniform)
    big, small = 0.05, 0.02
    u, v = rng.uniform(0, 2 * np.pi, k), rng.uniform(0, 2 * np.pi, k)
    keep = rng.uniform(0, big + small, k) < big + small * np.cos(v)
    u, v = u[keep], v[keep]
    nrm = np.column_stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)])
    centre = np.column_stack([big * np.cos(u), big * np.sin(u), np.zeros(len(u))])
    return centre + small * nrm, nrm


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=-1, keepdims=True)
