"""``forest_path``: a unidirectional path tracer over forest's own buffers, with path replay for gradients.

The estimator (Kajiya 1986; Veach 1997) at each path vertex x with incoming
direction ωi, throughput β and BSDF f:

* **emission** — a ray that leaves the scene in direction ω adds
  β · w_b · L(ω), with w_b = p_b² / (p_b² + p_L²) the power heuristic
  (Veach 1997, §9.2.4) of the BSDF sample that produced it against the light
  sampling density p_L (1 for camera rays);
* **next-event estimation** — a light direction ω_l ~ p_L (see
  :mod:`.emitters`) adds β · w_l · f(ωi, ω_l)|cos θ_l| · L(ω_l) · V(x, ω_l) / p_L(ω_l)
  with w_l = p_L² / (p_L² + p_b²), where V ∈ [0, 1] is the product of
  (1 − α) over the cut-out surfaces the shadow ray crosses (0 at an opaque one:
  alpha-cut leaves cast partial shadows, deterministically);
* **continuation** — ωo ~ p_b (the BSDF's lobes, :mod:`.materials`),
  β ← β · f|cos θo| / p_b; from depth ``rr_depth`` on, Russian roulette keeps the
  path with probability q = min(max β, 0.95) and divides β by q.

Camera and bounce rays pass through cut-out texels stochastically: a hit of
opacity α stops the ray with probability α (else the ray continues from just
past the surface, at most :data:`MAX_SKIPS` times), the estimator Mitsuba's
``mask`` BSDF uses.  The random numbers of these tests come from a per-lane
PCG32 stream (O'Neill 2014), so the sampler's dimensions stay aligned across lanes.

Hits come from ``Scene.ray_intersect_preliminary`` and are rebuilt by
:mod:`.geometry`: no surface interaction, BSDF or emitter is ever asked of
Mitsuba's shapes, so the quadratic instancing cost of the JIT variants never
arises.  Depth semantics follow Mitsuba's ``prb``: ``max_depth`` = 1 shows
only the sky, 2 adds direct light, 3 one bounce of indirect light, and so on.

**Gradients** (colour grid, light scales): Path Replay Backpropagation
(Vicini, Speierer & Jakob 2021), structured like Mitsuba's ``prb.py``.  A
primal pass computes the pixel radiance L; a second pass replays the same
paths (same sampler, same PCG32 streams) with L as its state, subtracting each
vertex's emitted and directly reflected radiance so that at vertex k it holds
the radiance L_k arriving along the rest of the path, and differentiates

    Lo_k = Le_k + Lr,dir,k + L_k · f_k(ωo) / detach(f_k(ωo))

at that vertex only: reverse mode calls ``dr.backward_from(δL · Lo_k)``,
forward mode accumulates ``dr.forward_to(Lo_k)``.  Sampling is detached (the
paths do not depend on the parameters), which is exact here because geometry
and visibility do not depend on albedos or light scales.  Memory stays
constant in the path length.

No construct here is specific to LLVM: the loops are drjit symbolic loops and
everything else is gathers, texture lookups and Mitsuba's native ray queries,
which ``cuda_ad_rgb`` provides as well.
"""

from __future__ import annotations

from .geometry import Hit, PartArrays, TraversalScene, hit_uv, resolve, surface
from .materials import MaterialArrays, bsdf_eval, bsdf_sample, shading

#: Cut-out surfaces a camera, bounce or shadow ray may pass before it is taken as blocked.
MAX_SKIPS = 24
#: Mitsuba's ray offset: (1 + max |x_i|) · 1500 · 2⁻²⁴ metres along the geometric normal.
RAY_EPSILON = 1500.0 * 2.0**-24
#: Alpha at or above which the pixel-centre layers pass takes a hit as opaque.
LAYER_ALPHA = 0.5


def mis_weight(pdf_a, pdf_b):
    """Power heuristic p_a² / (p_a² + p_b²) (0 where both are 0)."""
    import drjit as dr

    a2 = dr.square(pdf_a)
    s = a2 + dr.square(pdf_b)
    return dr.select(s > 0.0, a2 / s, 0.0)


class PathKernel:
    """Everything one render reads: traversal tables, part buffers, materials, textures, lights, settings."""

    def __init__(
        self,
        mi,
        scene: TraversalScene,
        parts: PartArrays,
        mats: MaterialArrays,
        *,
        grid,
        terrain_map,
        extent,
        lights,
        max_depth: int,
        rr_depth: int,
    ):
        self.mi = mi
        self.scene = scene
        self.parts = parts
        self.mats = mats
        self.grid = grid
        self.terrain_map = terrain_map
        self.extent = tuple(float(v) for v in extent)
        self.lights = lights
        self.max_depth = int(max_depth)
        self.rr_depth = int(rr_depth)

    # -- rays -------------------------------------------------------------------------
    def offset(self, p, ng, d):
        """Origin for a ray leaving ``p`` along ``d``: pushed off the surface to ``d``'s side (as Mitsuba)."""
        import drjit as dr

        mag = (1.0 + dr.max(dr.abs(p))) * RAY_EPSILON
        side = dr.select(dr.dot(ng, d) >= 0.0, mag, -mag)
        return dr.fma(ng, side, p)

    def _hit(self, o, d, maxt, active, coherent: bool = False) -> Hit:
        mi = self.mi
        ray = mi.Ray3f(o, d, maxt, 0.0, mi.Color0f())
        pi = self.scene.scene.ray_intersect_preliminary(ray, coherent=coherent, active=active)
        return resolve(mi, self.scene, self.parts, pi, active)

    def _alpha(self, hit: Hit, active):
        import drjit as dr

        mi = self.mi
        material = dr.gather(mi.UInt32, self.parts.material, hit.part, active)
        return self.mats.alpha(mi, material, hit_uv(mi, self.parts, hit, active), active)

    def _past(self, origin, d, t):
        """Distance to advance along ``d`` to leave a surface hit at distance ``t`` behind (Mitsuba's ray epsilon)."""
        import drjit as dr

        return t + (1.0 + dr.max(dr.abs(dr.fma(d, t, origin)))) * RAY_EPSILON

    def trace(self, o, d, maxt, rng, active, threshold: float | None = None, coherent: bool = False):
        """The first surface along a ray that is not a skipped cut-out texel.

        Returns (valid, t from ``o``, row, p, n_geo, n_sh, uv, material, rng).
        With ``threshold`` (the layers pass) a texel is opaque when α ≥ threshold;
        otherwise it stops the ray with probability α, drawn from ``rng``.  A
        skipped texel costs one traversal, the hit's triangle and uv and one
        texture lookup; only the surface finally hit is rebuilt in full.
        """
        import drjit as dr

        mi = self.mi
        hit = self._hit(o, d, maxt, active, coherent)
        if self.mats.has_cutouts:
            u = rng.next_float32() if threshold is None else mi.Float(threshold)
            through = hit.valid & (u >= self._alpha(hit, hit.valid))
            state = (
                hit.valid, hit.t, hit.row, hit.tri, hit.part, hit.b1, hit.b2,
                mi.Float(0.0), through, mi.UInt32(0), rng, mi.Point3f(o), mi.Float(maxt), mi.Vector3f(d),
            )  # fmt: skip

            def cond(valid, t, row, tri, part, b1, b2, base, through, skips, rng, origin, remaining, d):
                return through

            def body(valid, t, row, tri, part, b1, b2, base, through, skips, rng, origin, remaining, d):
                step = self._past(origin, d, t - base)
                origin = dr.fma(d, step, origin)
                remaining = remaining - step
                base = base + step
                skips = skips + 1
                h = self._hit(origin, d, remaining, through, coherent)
                u = rng.next_float32() if threshold is None else mi.Float(threshold)
                again = h.valid & (u >= self._alpha(h, h.valid)) & (skips < MAX_SKIPS)
                valid = dr.select(through, h.valid, valid)
                t = dr.select(through, base + h.t, t)
                row = dr.select(through, h.row, row)
                tri = dr.select(through, h.tri, tri)
                part = dr.select(through, h.part, part)
                b1 = dr.select(through, h.b1, b1)
                b2 = dr.select(through, h.b2, b2)
                through = through & again
                return valid, t, row, tri, part, b1, b2, base, through, skips, rng, origin, remaining, d

            out = dr.while_loop(state, cond, body, label="forest_path: cut-outs")
            hit = Hit(*out[:7])
            rng = out[10]
        sp = surface(mi, self.scene, self.parts, hit, hit.valid)
        return hit.valid, hit.t, hit.row, sp.p, sp.n_geo, sp.n_sh, sp.uv, sp.material, rng

    def transmittance(self, p, ng, d, active):
        """V = Π (1 − α) over the surfaces a ray from ``p`` towards a light at infinity crosses."""
        import drjit as dr

        mi = self.mi
        o = self.offset(p, ng, d)
        # An any-hit query first (≈ 8× cheaper than a closest hit here): open sky needs nothing more.
        blocked = self.scene.scene.ray_test(mi.Ray3f(o, d, dr.inf, 0.0, mi.Color0f()), active)
        if not self.mats.has_cutouts:
            return dr.select(active & ~blocked, 1.0, 0.0)
        active = active & blocked

        def cond(vis, live, origin, skips, d):
            return live

        def body(vis, live, origin, skips, d):
            h = self._hit(origin, d, dr.inf, live)
            vis = dr.select(h.valid, vis * (1.0 - self._alpha(h, h.valid)), vis)
            skips = skips + 1
            vis = dr.select(h.valid & (skips >= MAX_SKIPS), 0.0, vis)
            live = live & h.valid & (vis > 0.0)
            origin = dr.select(live, dr.fma(d, self._past(origin, d, h.t), origin), origin)
            return vis, live, origin, skips, d

        state = (mi.Float(1.0), mi.Bool(active), mi.Point3f(o), mi.UInt32(0), mi.Vector3f(d))
        vis, *_ = dr.while_loop(state, cond, body, label="forest_path: shadow")
        return vis

    # -- the estimator ------------------------------------------------------------------
    def sample(self, mode, sampler, ray, δL, state_in, active):
        """One path per lane: (L or δL, hit flag of the camera ray, L as state).  See the module docstring."""
        import drjit as dr

        mi = self.mi
        primal = mode == dr.ADMode.Primal
        n = dr.width(ray.d)
        # Per-lane PCG32 stream for cut-out tests, seeded from the sampler (replayed identically).
        seed = dr.reinterpret_array(mi.UInt32, sampler.next_1d())
        rng = mi.PCG32(size=n, initstate=mi.UInt64(seed), initseq=mi.UInt64(dr.arange(mi.UInt32, n)))
        o = mi.Point3f(dr.detach(ray.o))
        d = mi.Vector3f(dr.detach(ray.d))
        valid, _, _, p, ng, ns, uv, material, rng = self.trace(o, d, mi.Float(ray.maxt), rng, active)
        covered = mi.Bool(valid)
        L = mi.Color3f(0.0) if primal else mi.Color3f(state_in)
        δL = mi.Color3f(δL if δL is not None else 0.0)
        β = mi.Color3f(1.0)
        depth = mi.UInt32(0)
        prev_pdf = mi.Float(1.0)
        prev_delta = mi.Bool(True)
        active = mi.Bool(active)
        lights = self.lights
        state = (L, δL, β, depth, prev_pdf, prev_delta, active, d, valid, p, ng, ns, uv, material, rng, sampler)

        def cond(L, δL, β, depth, prev_pdf, prev_delta, active, d, valid, p, ng, ns, uv, material, rng, sampler):
            return active

        def body(L, δL, β, depth, prev_pdf, prev_delta, active, d, valid, p, ng, ns, uv, material, rng, sampler):
            # ---- light reaching the previous vertex from where this ray left the scene
            escaped = active & ~valid
            p_light = lights.pdf(d, escaped)
            mis = dr.select(prev_delta, 1.0, mis_weight(prev_pdf, p_light))
            with dr.resume_grad(when=not primal):
                Le = β * mis * lights.eval(d, escaped)
            active_next = active & valid
            # ---- the surface
            wi = -d
            # Two-sided: seen from behind, the surface shades as its front (Mitsuba's ``twosided``).
            flip = dr.dot(ns, wi) < 0.0
            ng = dr.select(flip, -ng, ng)
            ns = dr.select(flip, -ns, ns)
            with dr.resume_grad(when=not primal):
                sh = shading(mi, self.mats, material, uv, p, self.grid, self.extent, self.terrain_map, active_next)
            # ---- next-event estimation
            active_em = active_next & (depth + 1 < self.max_depth)
            u_pick = sampler.next_1d(active_em)
            u_dir = sampler.next_2d(active_em)
            dl, pdf_l = lights.sample_direction(u_pick, u_dir, active_em)
            # No shadow ray where the light sample cannot contribute (behind an opaque surface, no light).
            f_probe, _ = bsdf_eval(mi, sh.detached(), ns, wi, dl)
            active_em &= (pdf_l > 0.0) & (dr.max(f_probe) > 0.0)
            vis = self.transmittance(p, ng, dl, active_em)
            active_em &= vis > 0.0
            with dr.resume_grad(when=not primal):
                f_l, pdf_b = bsdf_eval(mi, sh, ns, wi, dl)
                Ll = lights.eval(dl, active_em)
                w_l = mis_weight(pdf_l, dr.detach(pdf_b))
                Lr_dir = dr.select(active_em, β * f_l * Ll * (w_l * vis / dr.maximum(pdf_l, 1e-30)), 0.0)
            # ---- continue the path
            active_next &= depth + 1 < self.max_depth
            u_lobe = sampler.next_1d(active_next)
            u_bsdf = sampler.next_2d(active_next)
            frame = mi.Frame3f(ns)
            wo, weight, pdf_o = bsdf_sample(mi, sh.detached(), frame, u_lobe, u_bsdf)
            active_next &= pdf_o > 0.0
            L = (L + Le + Lr_dir) if primal else (L - Le - Lr_dir)
            if not primal:
                with dr.resume_grad():
                    f_o, _ = bsdf_eval(mi, sh, ns, wi, wo)
                    Lr_ind = L * dr.select(active_next, dr.relative_grad(f_o), 0.0)
                    Lo = Le + Lr_dir + Lr_ind
                    if mode == dr.ADMode.Backward:
                        dr.backward_from(δL * Lo)
                    else:
                        δL += dr.forward_to(Lo)
            β = β * dr.select(active_next, weight, 0.0)
            prev_pdf = pdf_o
            prev_delta = mi.Bool(False)
            # ---- Russian roulette
            β_max = dr.max(β)
            active_next &= β_max > 0.0
            q = dr.minimum(β_max, 0.95)
            rr = depth >= self.rr_depth
            u_rr = sampler.next_1d(active_next)
            β = dr.select(rr, β / dr.maximum(q, 1e-12), β)
            active_next &= ~rr | (u_rr < q)
            # ---- the next surface
            o_next = self.offset(p, ng, wo)
            v2, _, _, p2, ng2, ns2, uv2, m2, rng = self.trace(o_next, wo, mi.Float(dr.inf), rng, active_next)
            d = dr.select(active_next, wo, d)
            valid = dr.select(active_next, v2, False)
            p, ng, ns, uv, material = p2, ng2, ns2, uv2, m2
            # A lane whose new ray escaped stays active one more iteration to collect the sky it sees.
            depth = dr.select(active & valid, depth + 1, depth)
            active = active_next
            return L, δL, β, depth, prev_pdf, prev_delta, active, d, valid, p, ng, ns, uv, material, rng, sampler

        state = dr.while_loop(state, cond, body, label="forest_path")
        L, δL = state[0], state[1]
        return (L if primal else δL), covered, L


_CLASSES: dict[str, type] = {}


def integrator_class(mi) -> type:
    """``forest_path`` as a Mitsuba integrator class for the active variant (registered on first use).

    It derives from Mitsuba's ``RBIntegrator`` (the base of ``prb``), so ``mi.render(scene, params,
    sensor=..., integrator=...)`` renders and differentiates it like Mitsuba's
    ``prb``; the instance must be bound to a :class:`PathKernel` (``bind``) —
    :meth:`forest.render.path.PathScene.integrator` returns one ready to use
    with ``PathScene.traversal.scene``.
    """
    variant = mi.variant()
    if variant in _CLASSES:
        return _CLASSES[variant]
    from mitsuba.python.ad.integrators.common import RBIntegrator as base

    class ForestPathIntegrator(base):
        def __init__(self, props):
            super().__init__(props)
            self.kernel: PathKernel | None = None

        def bind(self, kernel: PathKernel):
            self.kernel = kernel
            self.max_depth = kernel.max_depth
            return self

        def sample(self, mode, scene, sampler, ray, δL, state_in, active, **kwargs):
            if self.kernel is None:
                raise RuntimeError("forest_path: bind the integrator to a PathKernel first (PathScene.integrator())")
            L, valid, state = self.kernel.sample(mode, sampler, ray, δL, state_in, active)
            return L, valid, [], state

        def aov_names(self):
            return []

        def to_string(self):
            return "ForestPathIntegrator[]"

    mi.register_integrator("forest_path", lambda props: ForestPathIntegrator(props))
    _CLASSES[variant] = ForestPathIntegrator
    return ForestPathIntegrator
