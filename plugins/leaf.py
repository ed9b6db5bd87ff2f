"""``forest_leaf``: a thin-leaf BSDF with Lambertian reflection and diffuse transmission.

Mitsuba 3.9.1 has no diffuse transmitter, and foliage lit from behind glows
because leaves pass on a large share of the light (Jacquemoud & Baret 1990,
PROSPECT; typical visible transmittance 0.05–0.45).  The model, for albedos
R (reflectance) and T (transmittance) with R + T ≤ 1:

    f(ωi, ωo) = R/π   when ωi and ωo lie on the same side of the leaf,
              = T/π   otherwise.

Sampling picks reflection with probability p = |R| / (|R| + |T|) (channel
means), then a cosine-weighted direction on the chosen side, so the sample
weight f·|cos θo| / pdf is R/p or T/(1−p).  It is two-sided: the leaf's back
reflects like its front.

Written in Python, the BSDF is traced once per kernel in the JIT variants
(no run-time cost) but called per sample in ``scalar_rgb``; the renderer
measures and chooses (see ``forest.render.materials``).
"""

from __future__ import annotations

NAME = "forest_leaf"


def make_class(mi):
    """Build the BSDF class for the active variant (Mitsuba types are variant-specific)."""
    import drjit as dr

    def texture(props, name, default):
        if name in props:
            return props.get_texture(name)
        return mi.load_dict({"type": "uniform", "value": default})

    class LeafBSDF(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.reflectance = texture(props, "reflectance", 0.4)
            self.transmittance = texture(props, "transmittance", 0.2)
            refl = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            trans = mi.BSDFFlags.DiffuseTransmission | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            self.m_components = [refl, trans]
            self.m_flags = refl | trans

        def _albedos(self, si, active):
            r = self.reflectance.eval(si, active)
            t = self.transmittance.eval(si, active)
            mr = (r[0] + r[1] + r[2]) * (1.0 / 3.0)
            mt = (t[0] + t[1] + t[2]) * (1.0 / 3.0)
            p = dr.select(mr + mt > 0, mr / dr.maximum(mr + mt, 1e-8), 1.0)
            return r, t, p

        def _probability(self, ctx, p):
            has_r = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
            has_t = ctx.is_enabled(mi.BSDFFlags.DiffuseTransmission, 1)
            if has_r and not has_t:
                return dr.ones(mi.Float, dr.width(p)) if dr.is_jit_v(mi.Float) else 1.0
            if has_t and not has_r:
                return dr.zeros(mi.Float, dr.width(p)) if dr.is_jit_v(mi.Float) else 0.0
            return p

        def sample(self, ctx, si, sample1, sample2, active=True):
            r, t, p = self._albedos(si, active)
            p = self._probability(ctx, p)
            cos_i = mi.Frame3f.cos_theta(si.wi)
            reflect = sample1 < p
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            side = dr.select(cos_i >= 0, 1.0, -1.0)
            wo_z = dr.select(reflect, side, -side) * dr.abs(wo.z)
            wo = mi.Vector3f(wo.x, wo.y, wo_z)
            bs = mi.BSDFSample3f()
            bs.wo = wo
            cos_pdf = mi.warp.square_to_cosine_hemisphere_pdf(mi.Vector3f(wo.x, wo.y, dr.abs(wo_z)))
            bs.pdf = dr.select(reflect, p, 1.0 - p) * cos_pdf
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(
                dr.select(
                    reflect, mi.UInt32(+mi.BSDFFlags.DiffuseReflection), mi.UInt32(+mi.BSDFFlags.DiffuseTransmission)
                )
            )
            bs.sampled_component = mi.UInt32(dr.select(reflect, mi.UInt32(0), mi.UInt32(1)))
            weight = dr.select(reflect, r / dr.maximum(p, 1e-8), t / dr.maximum(1.0 - p, 1e-8))
            ok = active & (bs.pdf > 0)
            return bs, dr.select(ok, weight, 0.0)

        def eval(self, ctx, si, wo, active=True):
            r, t, _ = self._albedos(si, active)
            cos_i = mi.Frame3f.cos_theta(si.wi)
            cos_o = mi.Frame3f.cos_theta(wo)
            same = cos_i * cos_o > 0
            has_r = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0)
            has_t = ctx.is_enabled(mi.BSDFFlags.DiffuseTransmission, 1)
            f = dr.select(same, r if has_r else 0.0, t if has_t else 0.0) * (dr.abs(cos_o) * dr.inv_pi)
            return dr.select(active, f, 0.0)

        def pdf(self, ctx, si, wo, active=True):
            _, _, p = self._albedos(si, active)
            p = self._probability(ctx, p)
            cos_i = mi.Frame3f.cos_theta(si.wi)
            cos_o = mi.Frame3f.cos_theta(wo)
            same = cos_i * cos_o > 0
            return dr.select(active, dr.select(same, p, 1.0 - p) * dr.abs(cos_o) * dr.inv_pi, 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, callback):
            callback.put("reflectance", self.reflectance, mi.ParamFlags.Differentiable)
            callback.put("transmittance", self.transmittance, mi.ParamFlags.Differentiable)

        def to_string(self):
            return f"LeafBSDF[reflectance={self.reflectance}, transmittance={self.transmittance}]"

    return LeafBSDF


def register(mi) -> None:
    cls = make_class(mi)
    mi.register_bsdf(NAME, lambda props: cls(props))
