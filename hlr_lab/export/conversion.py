"""From hlr-lab's Blinn-Phong parameters to what other tools speak.

hlr-lab's model (paper eq. 1): I = L (Rd cos α + Rs cosⁿβ), β between the normal and the half vector;
L is the irradiance, expressed so that a white Lambertian surface facing the light reads L — so Rd is
the diffuse albedo, and the specular term is not normalised.

* Blinn-Phong exponent → microfacet roughness (Walter et al. 2007, "Microfacet models for refraction"):
  a Beckmann distribution of roughness α matches cosⁿ θh for n = 2/α² − 2, so α = √(2 / (n + 2)).
  glTF's ``roughnessFactor`` r has α = r², so r = α^½.
* Specular reflectance → Fresnel F0: a normalised Blinn-Phong lobe (n + 8)/(8π) · F0 · cosⁿθh, in the
  irradiance convention above (× π), peaks at F0 (n + 8)/8 at normal incidence. Matching the measured
  peak Rs gives F0 = 8 Rs / (n + 8).
* A dielectric's F0 is ((η − 1)/(η + 1))², 0.04 at IOR 1.5: glTF's KHR_materials_specular
  ``specularColorFactor`` scales that base, so it is F0 / 0.04; Mitsuba's reflectances must stay in
  [0, 1], so there the IOR itself carries F0 (η = (1 + √F0)/(1 − √F0)).

These are approximations (a microfacet lobe is not exactly cosⁿ, and the Fresnel term varies with
angle); the exact fitted numbers travel along in each export (comments in the MTL, ``extras`` in glTF,
comments in the Mitsuba scene).
"""

from __future__ import annotations

import numpy as np

GLTF_DIELECTRIC_F0 = 0.04  # IOR 1.5
MITSUBA_PLASTIC_IOR = 1.49  # roughplastic's default int_ior


def beckmann_alpha(n: float) -> float:
    """The Beckmann roughness α matching Blinn-Phong exponent ``n``: √(2 / (n + 2))."""
    return float(np.sqrt(2.0 / (n + 2.0)))


def gltf_roughness(n: float) -> float:
    """glTF's ``roughnessFactor`` for exponent ``n``: √α (glTF squares it into α)."""
    return float(np.sqrt(beckmann_alpha(n)))


def specular_f0(rs: np.ndarray, n: float) -> np.ndarray:
    """Fresnel F0 per channel, (3,), matching the peak of the measured lobe: 8 Rs / (n + 8)."""
    return 8.0 * np.asarray(rs, dtype=np.float64) / (n + 8.0)


def dielectric_f0(ior: float) -> float:
    """A dielectric's normal-incidence reflectance for index of refraction ``ior``: ((η − 1)/(η + 1))²."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def ior_for_f0(f0: float) -> float:
    """The IOR whose normal-incidence Fresnel reflectance is ``f0`` (0 < f0 < 1)."""
    r = np.sqrt(np.clip(f0, 1e-12, 0.99))
    return float((1.0 + r) / (1.0 - r))
