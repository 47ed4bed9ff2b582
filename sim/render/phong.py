"""hlr-lab's reflection model as a Mitsuba BSDF: BSDF value × cos = (Rd cos α + Rs cosⁿβ) / π.

The 1/π makes a white Lambertian (Rd = 1) under a point light of Mitsuba intensity π·Φ read Φ/d² facing
it — the project's irradiance convention (docs/conventions.md), so rendered values are eq. (1) exactly. Sampling
is cosine-weighted (the direct integrator samples the light; the path tracer also samples this).
``dr.select`` rather than ``dr.maximum``: LLVM 15 could not compile the latter in a custom BSDF.
"""

# Mitsuba's stubs describe its C++ classes; a Python plugin written after its documented pattern (fields of
# a BSDFSample3f set, traverse overridden, Dr.Jit arithmetic on parameters) looks wrong to them
# pyright: reportAttributeAccessIssue=false, reportIncompatibleMethodOverride=false, reportOperatorIssue=false

from __future__ import annotations

import drjit as dr
import mitsuba as mi

PLUGIN = "hlr_phong"


class PhongBSDF(mi.BSDF):
    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.rd = mi.Color3f(props["rd"])
        self.rs = mi.Color3f(props["rs"])
        self.n = mi.Float(props["n"])
        self._set_flags()

    def _set_flags(self) -> None:
        flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
        self.m_components = [flags]
        self.m_flags = flags

    def material(self, si):
        """(rd, rs, n) at the surface point (the same everywhere for one region)."""
        return self.rd, self.rs, self.n

    def eval(self, ctx, si, wo, active=True):
        cos_view, cos_light = mi.Frame3f.cos_theta(si.wi), mi.Frame3f.cos_theta(wo)
        h = dr.normalize(si.wi + wo)
        cos_beta = dr.select(h.z > 0, h.z, 0.0)
        rd, rs, n = self.material(si)
        value = (rd * cos_light + rs * dr.power(cos_beta, n)) * dr.inv_pi
        return dr.select(active & (cos_view > 0) & (cos_light > 0), value, 0.0)

    def pdf(self, ctx, si, wo, active=True):
        ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        return dr.select(ok, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        bs = mi.BSDFSample3f()
        bs.wo = mi.warp.square_to_cosine_hemisphere(sample2)
        bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(bs.wo)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
        bs.sampled_component = mi.UInt32(0)
        ok = active & (bs.pdf > 0)
        weight = self.eval(ctx, si, bs.wo, ok) / dr.select(ok, bs.pdf, 1.0)
        return bs, dr.select(ok, weight, 0.0)

    def traverse(self, callback):
        callback.put("rd", self.rd, mi.ParamFlags.NonDifferentiable)
        callback.put("rs", self.rs, mi.ParamFlags.NonDifferentiable)
        callback.put("n", self.n, mi.ParamFlags.NonDifferentiable)

    def to_string(self):
        return f"PhongBSDF[rd={self.rd}, rs={self.rs}, n={self.n}]"


class RegionMapPhongBSDF(PhongBSDF):
    """eq. (1) with the material chosen per texel: ``region_map`` is a texture of region indices (nearest
    filtering, raw values) and ``rd``/``rs``/``n`` are tables with one entry per region — so a region
    border may cross a face, exactly as the texture paints it."""

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.region_map = props["region_map"]
        self.rd_table = mi.Float(props["rd_table"])
        self.rs_table = mi.Float(props["rs_table"])
        self.n_table = mi.Float(props["n_table"])
        self._set_flags()

    def material(self, si):
        index = mi.UInt32(dr.round(self.region_map.eval_1(si)))
        return (
            dr.gather(mi.Color3f, self.rd_table, index),
            dr.gather(mi.Color3f, self.rs_table, index),
            dr.gather(mi.Float, self.n_table, index),
        )

    def traverse(self, callback):
        callback.put("n_table", self.n_table, mi.ParamFlags.NonDifferentiable)

    def to_string(self):
        return "RegionMapPhongBSDF"


MAP_PLUGIN = "hlr_phong_map"
_registered = False


def register() -> None:
    global _registered
    if not _registered:
        mi.register_bsdf(PLUGIN, lambda props: PhongBSDF(props))
        mi.register_bsdf(MAP_PLUGIN, lambda props: RegionMapPhongBSDF(props))
        _registered = True
