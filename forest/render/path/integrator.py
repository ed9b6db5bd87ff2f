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
* **continuation** — ωo ~ p_b (the BSDF's lobes, :mod:`.materials`; a leaf's cuticle
  lobe is sampled too, and p_b is then the lobes' mixture density),
  β ← β · f|cos θo| / p_b (a water mirror, :func:`.materials.water_lobe`, is a delta lobe:
  picked with probability p, β ← β · W·F / p, no light sampling on it, and the ray that
  leaves the scene after it takes the sky with weight 1, as after Mitsuba's ``dielectric``);
  from depth ``rr_depth`` on, Russian roulette keeps the
  path with probability q = min(max β, 0.95) and divides β by q.

* **aerial perspective** — each camera or bounce segment of length ℓ that ends
  on a surface (and a camera ray that leaves the scene) passes through the
  haze of :mod:`.haze`: L += β·(1 − T)·J(d), β ← β·T.
* **light shafts** (the haze's ``shafts``, primal renders) — on a camera ray the
  sun's share of J is shadowed: each step k of the ray (the segments between
  passed texels) draws a scattering point s*_k ~ σT (:meth:`.haze.HazeModel.sample_distance`)
  and has the unshadowed value c_k = β·(1 − T_k)·E_sun p; one point j is kept by
  weighted reservoir sampling (Chao 1982; Talbot et al. 2005, "Importance
  resampling for global illumination"), w_k = mean(c_k), and when the camera
  ray stops one shadow ray from s*_j toward a point of the sun's disc (uniform in
  its cone, as the disc's soft shadows on surfaces) adds (Σ_k w_k)·c_j/w_j·V(s*_j)
  — unbiased for Σ_k c_k V(s*_k), at the cost of one shadow chain per camera
  ray; V includes the cloud layer's transmittance toward the sun, as a surface's
  sun does (:meth:`.clouds.CloudLayer.transmittance`), so cloud shadows fall on
  the haze as on the ground.  The ambient share C keeps its closed form; bounce
  segments keep the unshadowed J.  Off in gradient renders (look-dev fits the
  unshadowed haze).

Camera and bounce rays pass through cut-out texels stochastically: a hit of
opacity α stops the ray with probability α (else the ray continues from just
past the surface, at most :data:`MAX_SKIPS` times), the estimator Mitsuba's
``mask`` BSDF uses.  The random numbers of these tests come from a per-lane
PCG32 stream (O'Neill 2014).  The whole path runs as one loop in which every
iteration traces one ray segment per lane (see :meth:`PathKernel.sample`).

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
forward mode accumulates ``dr.forward_to(Lo_k)``.  A hazed segment is a
vertex of its own: with the radiance L arriving through it,
Lo = (1 − T)·J + L · T / detach(T) is differentiated there (haze density,
height, colour and anisotropy, and the sun scale through J).  Sampling is detached (the
paths do not depend on the parameters), which is exact here because geometry
and visibility do not depend on albedos or light scales.  Memory stays
constant in the path length.

No construct here is specific to LLVM: the loops are drjit symbolic loops and
everything else is gathers, texture lookups and Mitsuba's native ray queries,
which ``cuda_ad_rgb`` provides as well.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from .geometry import Hit, PartArrays, TraversalScene, hit_uv, resolve, surface
from .materials import MaterialArrays, TerrainMap, bsdf_eval, bsdf_sample, shading, water_coverage, water_lobe

if TYPE_CHECKING:
    from .emitters import LightSet
    from .haze import HazeModel

#: First-hit code of a path whose camera ray hit nothing (``PathKernel.sample(aux=True)``).
NO_HIT = 0xFFFFFFFF

#: Cut-out surfaces a camera, bounce or shadow ray may pass before it is taken as blocked.
MAX_SKIPS = 24


def segment_cap(max_depth: int, shafts: bool = False) -> int:
    """The most ray segments one path of :meth:`PathKernel.sample` can trace, by construction.

    A path has ``max_depth`` extension chains (camera or bounce ray), each at most
    :data:`MAX_SKIPS` passed texels and one stop, and ``max_depth − 1`` shadow chains, each at
    most :data:`MAX_SKIPS` segments (the last sets its visibility to 0):
    ``max_depth·(MAX_SKIPS + 1) + (max_depth − 1)·MAX_SKIPS``, and with light ``shafts`` one more
    shadow chain (the haze's, once per camera ray).  The segment loop stops a lane one
    segment past this, a guard that no path can reach unless the bound above is broken (a lane
    that reached it would lose its pending light, and its counter shows it).
    """
    d = max(1, int(max_depth))
    return d * (MAX_SKIPS + 1) + (d - 1) * MAX_SKIPS + (MAX_SKIPS if shafts else 0)


#: Mitsuba's ray offset: (1 + max |x_i|) · 1500 · 2⁻²⁴ metres along the geometric normal.
RAY_EPSILON = 1500.0 * 2.0**-24
#: Alpha at or above which the pixel-centre layers pass takes a hit as opaque.
LAYER_ALPHA = 0.5


def mis_weight(pdf_a: Any, pdf_b: Any) -> Any:
    """Power heuristic p_a² / (p_a² + p_b²) (0 where both are 0)."""
    import drjit as dr

    a2 = dr.square(pdf_a)
    s = a2 + dr.square(pdf_b)
    return dr.select(s > 0.0, a2 / s, 0.0)


class PathKernel:
    """Everything one render reads: traversal tables, part buffers, materials, textures, lights, settings."""

    def __init__(
        self,
        mi: Any,
        scene: TraversalScene,
        parts: PartArrays,
        mats: MaterialArrays,
        *,
        grid: Any,
        terrain_map: TerrainMap | None,
        extent: Iterable[float],
        lights: LightSet,
        max_depth: int,
        rr_depth: int,
        haze: HazeModel | None = None,
        water_ripple: float | None = None,
        row_tint: Any = None,
    ):
        self.mi = mi
        #: Each row's colour jitter j_r (Float, 3 per row, the identity row last; see .materials), or None.
        self.row_tint = row_tint
        self.haze = haze
        self.scene = scene
        self.parts = parts
        self.mats = mats
        self.grid = grid
        self.terrain_map = terrain_map
        self.extent = tuple(float(v) for v in extent)
        self.lights = lights
        self.max_depth = int(max_depth)
        self.rr_depth = int(rr_depth)
        #: Water on the terrain (its coverage the terrain map's fourth channel): ripple tilt in degrees, else None.
        self.water_ripple = None if water_ripple is None or terrain_map is None else float(water_ripple)

    # -- rays -------------------------------------------------------------------------
    def offset(self, p: Any, ng: Any, d: Any) -> Any:
        """Origin for a ray leaving ``p`` along ``d``: pushed off the surface to ``d``'s side (as Mitsuba)."""
        import drjit as dr

        mag = (1.0 + dr.max(dr.abs(p))) * RAY_EPSILON
        side = dr.select(dr.dot(ng, d) >= 0.0, mag, -mag)
        return dr.fma(ng, side, p)

    def _hit(self, o: Any, d: Any, maxt: Any, active: Any, coherent: bool = False) -> Hit:
        mi = self.mi
        ray = mi.Ray3f(o, d, maxt, 0.0, mi.Color0f())
        pi = self.scene.scene.ray_intersect_preliminary(ray, coherent=coherent, active=active)
        return resolve(mi, self.scene, self.parts, pi, active)

    def _alpha(self, hit: Hit, active: Any) -> Any:
        import drjit as dr

        mi = self.mi
        material = dr.gather(mi.UInt32, self.parts.material, hit.part, active)
        return self.mats.alpha(mi, material, hit_uv(mi, self.parts, hit, active), active)

    def _past(self, origin: Any, d: Any, t: Any) -> Any:
        """Distance to advance along ``d`` to leave a surface hit at distance ``t`` behind (Mitsuba's ray epsilon)."""
        import drjit as dr

        return t + (1.0 + dr.max(dr.abs(dr.fma(d, t, origin)))) * RAY_EPSILON

    def trace(
        self,
        o: Any,
        d: Any,
        maxt: Any,
        rng: Any,
        active: Any,
        threshold: float | None = None,
        coherent: bool = False,
    ) -> tuple[Any, ...]:
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

            # dr.while_loop hands cond the whole loop state
            def cond(valid: Any, t: Any, row: Any, tri: Any, part: Any, b1: Any, b2: Any, base: Any, through: Any, skips: Any, rng: Any, origin: Any, remaining: Any, d: Any) -> Any:  # noqa: ARG001  # fmt: skip
                return through

            def body(valid: Any, t: Any, row: Any, tri: Any, part: Any, b1: Any, b2: Any, base: Any, through: Any, skips: Any, rng: Any, origin: Any, remaining: Any, d: Any) -> tuple[Any, ...]:  # fmt: skip
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

    def first_hit(self, sampler: Any, ray: Any, active: Any) -> tuple[Any, Any, Any]:
        """What each camera ray meets first, passing cut-out texels stochastically as the beauty's rays do.

        Returns (row or :data:`NO_HIT`, albedo R + T, shading normal facing the camera): the
        per-sample ids, coverage and denoiser guides of a frame whose beauty another renderer made.
        """
        import drjit as dr

        mi = self.mi
        n = dr.width(ray.d)
        seed = dr.reinterpret_array(mi.UInt32, sampler.next_1d())
        rng = mi.PCG32(size=n, initstate=mi.UInt64(seed), initseq=mi.UInt64(dr.arange(mi.UInt32, n)))
        valid, _, row, p, _, n_sh, uv, material, _ = self.trace(ray.o, ray.d, ray.maxt, rng, active)
        sh = shading(
            mi, self.mats, material, uv, p, self.grid, self.extent, self.terrain_map, valid, row, self.row_tint,
            n_sh.y,
        )  # fmt: skip
        normal = dr.select(dr.dot(n_sh, ray.d) > 0.0, -n_sh, n_sh)
        albedo = dr.select(valid, sh.reflect + sh.transmit, 0.0)
        return dr.select(valid, row, NO_HIT), albedo, dr.select(valid, normal, 0.0)

    # -- the estimator ------------------------------------------------------------------
    def sample(
        self,
        mode: Any,
        sampler: Any,
        ray: Any,
        δL: Any,
        state_in: Any,
        active: Any,
        aux: bool = False,
        groups: bool = False,
    ) -> tuple[Any, ...]:
        """One path per lane: (L, or δL in a derivative mode; the camera ray's hit flag; L as state).

        ``aux`` (primal only) adds a fourth value, a dict of what the camera ray met first:
        ``row`` (the row of the surface the path's first vertex lies on — a tree, or the
        identity row for world-space parts — :data:`NO_HIT` where the camera ray left the
        scene), ``albedo`` (R + T there; the sky's radiance clamped to 1 where nothing
        was hit) and ``normal`` (the shading normal facing the camera) — the guides
        of a denoiser and the per-sample ids of coverage mattes — and ``segments``, the
        ray segments the path traced (at most :func:`segment_cap`; a per-lane counter
        for checking the loop's bound on any variant).

        ``groups`` (with ``aux``) adds ``groups`` to that dict: the path's radiance split by where
        the light came from, {``sun``, ``sky`` (:func:`.emitters.light_group`), ``haze``: Color3f}.
        Every term the estimator adds to L is added to exactly one group — an emission hit
        β·w_b·L_k(ω) and a next-event estimate β·w_l·f·L_k(ω_l)·V/p_L to the group of light k
        (the light sum Σ_k L_k split into its terms), the haze's in-scattering β·(1 − T)·J(d) to
        ``haze`` — so Σ_g L_g = L up to float rounding, from the same samples.  Off, the traced
        code is the one without groups.

        The estimator (module docstring) runs as one loop of ray *segments*.

        Each iteration traces exactly one ray per lane — a camera or bounce ray
        (past cut-out texels one segment at a time) or a shadow ray — and then
        does what that segment calls for: pass a texel, collect the sky, shade a
        vertex (sample a light and a direction, start its shadow ray), or finish
        a shadow.  Lanes of one SIMD packet therefore stay busy until their
        paths end, where nested loops (a skip loop inside a shadow loop inside
        the path loop) leave most lanes of a packet idle while one lane passes
        its many texels; a packet with 1 of 16 lanes active costs Embree about
        3.6× more per ray than a full one (``bench/bench_forest_path.py``).

        Path replay: the contributions of a vertex whose shadow ray is still
        under way — its direct light and the derivative of its BSDF along the
        continued path — are differentiated when the shadow ray finishes, from
        the vertex's cached hit (material, uv, position, normal, directions).
        The vertex's remaining radiance is then exactly what PRB needs there:
        everything later along the path has not been subtracted yet.
        """
        import drjit as dr

        mi = self.mi
        primal = mode == dr.ADMode.Primal
        aux = bool(aux) and primal
        lights = self.lights
        haze = self.haze
        lgroups = lights.groups if (groups and aux) else []
        n = dr.width(ray.d)
        seed = dr.reinterpret_array(mi.UInt32, sampler.next_1d())
        rng = mi.PCG32(size=n, initstate=mi.UInt64(seed), initseq=mi.UInt64(dr.arange(mi.UInt32, n)))
        zeros3 = mi.Vector3f(0.0)
        state = dict(
            L=mi.Color3f(0.0) if primal else mi.Color3f(state_in),
            δL=mi.Color3f(δL if δL is not None else 0.0),
            β=mi.Color3f(1.0),
            depth=mi.UInt32(0),
            prev_pdf=mi.Float(1.0),
            prev_delta=mi.Bool(True),
            active=mi.Bool(active),
            covered=mi.Bool(False),
            rng=rng,
            sampler=sampler,
            eo=mi.Point3f(dr.detach(ray.o)),
            ed=mi.Vector3f(dr.detach(ray.d)),
            emaxt=mi.Float(ray.maxt),
            eskips=mi.UInt32(0),
            shadowing=mi.Bool(False),
            so=mi.Point3f(0.0),
            sd=mi.Vector3f(0.0, 1.0, 0.0),
            vis=mi.Float(1.0),
            sskips=mi.UInt32(0),
            C=mi.Color3f(0.0),
            cont=mi.Bool(False),
            segments=mi.UInt32(0),
        )
        cumulus = lights.clouds is not None and lights.clouds.tall > 0.0
        if cumulus:  # the march's jitter through the cumulus a camera ray sees: stratified over a pixel's samples
            state["cjit"] = sampler.next_1d()
        if aux:
            state.update(first=mi.UInt32(NO_HIT), albedo=mi.Color3f(0.0), normal=mi.Vector3f(0.0))
        for g in lgroups:  # radiance gathered per light group, and the pending shadow ray's share of C
            state[f"G:{g}"] = mi.Color3f(0.0)
            state[f"C:{g}"] = mi.Color3f(0.0)
        if groups and aux and haze is not None:
            state["G:haze"] = mi.Color3f(0.0)
        shafts = primal and haze is not None and haze.shafts
        if shafts:  # the reservoir of the camera ray's scattering points, then the haze's shadow ray
            state.update(
                hw=mi.Float(0.0), hx=mi.Point3f(0.0), hc=mi.Color3f(0.0), hshadow=mi.Bool(False),
                hso=mi.Point3f(0.0), hsd=mi.Vector3f(0.0, 1.0, 0.0), hvis=mi.Float(1.0), hskips=mi.UInt32(0),
                hC=mi.Color3f(0.0),
            )  # fmt: skip
        if not primal:  # the vertex a pending shadow ray belongs to
            state.update(
                vp=mi.Point3f(0.0), vuv=mi.Point2f(0.0), vmat=mi.UInt32(0), vns=mi.Vector3f(zeros3),
                vwo=mi.Vector3f(zeros3), vdl=mi.Vector3f(zeros3), vβ=mi.Color3f(0.0), vw=mi.Float(0.0),
            )  # fmt: skip
            if self.mats.has_sheen:  # the leaf cuticle lobe also needs the direction towards the viewer
                state["vwi"] = mi.Vector3f(zeros3)
            if self.row_tint is not None:  # and the tree's colour jitter its row
                state["vrow"] = mi.UInt32(0)
        water = self.water_ripple is not None
        if water and not primal:  # the pending vertex's water: its diffuse factor 1 − W·F, a mirror sample
            state.update(vkeep=mi.Float(1.0), vspec=mi.Bool(False))
        keys = list(state)
        i_active, i_segments = keys.index("active"), keys.index("segments")
        i_hshadow = keys.index("hshadow") if shafts else None
        guard = segment_cap(self.max_depth, shafts) + 1  # a hard stop no path reaches (see segment_cap)

        def cond(*values: Any) -> Any:
            alive = values[i_active] if i_hshadow is None else values[i_active] | values[i_hshadow]
            return alive & (values[i_segments] < guard)

        # A term may not depend on the parameters being differentiated (the sky's emission when only the
        # colour grid has gradients): allowed here, since the terms are propagated one by one.
        flags = dr.ADFlag.Default | dr.ADFlag.AllowNoGrad

        def differentiate(S: dict[str, Any], Lo: Any) -> None:
            if mode == dr.ADMode.Backward:
                dr.backward_from(S["δL"] * Lo, flags=flags)
            else:
                S["δL"] = S["δL"] + dr.forward_to(Lo, flags=flags)

        def body(*values: Any) -> tuple[Any, ...]:
            S = dict(zip(keys, values))
            active = S["active"]
            S["segments"] = S["segments"] + 1
            hshadow = S["hshadow"] if shafts else mi.Bool(False)
            shadow = active & S["shadowing"] & ~hshadow
            o = dr.select(shadow, S["so"], S["eo"])
            d = dr.select(shadow, S["sd"], S["ed"])
            maxt = dr.select(shadow, dr.inf, S["emaxt"])
            if shafts:  # the haze's shadow ray goes first
                assert haze is not None
                o = dr.select(hshadow, S["hso"], o)
                d = dr.select(hshadow, S["hsd"], d)
                maxt = dr.select(hshadow, dr.inf, maxt)
            hit = self._hit(o, d, maxt, active | hshadow)
            alpha = self._alpha(hit, hit.valid) if self.mats.has_cutouts else mi.Float(1.0)

            # ---- the haze's shadow segment: attenuate, pass on, or add the shafts' light
            if shafts:
                hvis, S["hskips"], h_done, S["hso"] = self._shadow_step(
                    hshadow, S["hvis"], S["hskips"], S["hso"], o, d, hit, alpha
                )
                if lights.clouds is not None:  # the sun through the cloud layer, as a surface's shadow ray has it
                    hvis = dr.select(h_done, hvis * lights.clouds.transmittance(o, d, h_done)[0], hvis)
                S["hvis"] = hvis
                shaft = dr.select(h_done, S["hC"] * hvis, 0.0)
                S["L"] = S["L"] + shaft
                if "G:haze" in S:
                    S["G:haze"] = S["G:haze"] + shaft
                S["hshadow"] = hshadow & ~h_done

            # ---- a shadow segment: attenuate, pass on, or finish
            vis, S["sskips"], s_done, S["so"] = self._shadow_step(
                shadow, S["vis"], S["sskips"], S["so"], o, d, hit, alpha
            )
            S["vis"] = vis
            if primal:
                S["L"] = dr.select(s_done, S["L"] + S["C"] * vis, S["L"])
                for g in lgroups:
                    S[f"G:{g}"] = dr.select(s_done, S[f"G:{g}"] + S[f"C:{g}"] * vis, S[f"G:{g}"])
            else:
                with dr.resume_grad():
                    sh = shading(mi, self.mats, S["vmat"], S["vuv"], S["vp"], self.grid, self.extent,
                                 self.terrain_map, s_done, S.get("vrow"), self.row_tint, S["vns"].y)  # fmt: skip
                    if water:
                        sh = replace(sh, reflect=sh.reflect * S["vkeep"])
                    f_l, _ = bsdf_eval(sh, S["vns"], S["vdl"], S.get("vwi"))
                    Lr_dir = dr.select(
                        s_done, S["vβ"] * f_l * lights.eval(S["vdl"], s_done, S["vp"]) * (S["vw"] * vis), 0.0
                    )
                L = dr.select(s_done, S["L"] - dr.detach(Lr_dir), S["L"])
                with dr.resume_grad():
                    f_o, _ = bsdf_eval(sh, S["vns"], S["vwo"], S.get("vwi"))
                    along = S["cont"] & ~S["vspec"] if water else S["cont"]  # a mirror sample has no gradient
                    Lr_ind = L * dr.select(s_done & along, dr.relative_grad(f_o), 0.0)
                    differentiate(S, Lr_dir + Lr_ind)
                S["L"] = L
            S["shadowing"] = S["shadowing"] & ~s_done
            active = active & ~(s_done & ~S["cont"])

            # ---- an extension segment (camera or bounce ray): pass a cut-out texel, leave, or stop
            ext = active & ~shadow & ~hshadow
            if haze is not None:
                self._haze_step(S, haze, o, d, hit, ext, primal, differentiate, shafts)
            u = S["rng"].next_float32()
            through = ext & hit.valid & (u >= alpha) & (S["eskips"] < MAX_SKIPS)
            step = self._past(o, d, hit.t)
            S["eo"] = dr.select(through, dr.fma(d, step, o), S["eo"])
            S["emaxt"] = dr.select(through, S["emaxt"] - step, S["emaxt"])
            S["eskips"] = dr.select(through, S["eskips"] + 1, S["eskips"])
            stop = ext & ~through
            if shafts:  # the camera ray ends: its kept scattering point starts the haze's shadow ray
                assert haze is not None
                start = stop & (S["depth"] == 0) & (S["hw"] > 0.0)
                S["hshadow"] = S["hshadow"] | start
                S["hso"] = dr.select(start, S["hx"], S["hso"])
                u_disc = mi.Point2f(S["rng"].next_float32(), S["rng"].next_float32())
                S["hsd"] = dr.select(start, haze.sun_ray(u_disc), S["hsd"])
                S["hC"] = dr.select(start, S["hc"] * S["hw"], S["hC"])
                S["hvis"] = dr.select(start, 1.0, S["hvis"])
                S["hskips"] = dr.select(start, 0, S["hskips"])
                S["hw"] = dr.select(start, 0.0, S["hw"])
            escaped = stop & ~hit.valid
            vertex = stop & hit.valid
            S["covered"] = S["covered"] | (vertex & (S["depth"] == 0))
            # Light from where the ray left the scene, weighed against light sampling (power heuristic).
            mis = dr.select(S["prev_delta"], 1.0, mis_weight(S["prev_pdf"], lights.pdf(d, escaped)))
            # A camera ray that leaves sees the backdrop where an environment map lights but is not seen.
            seen = escaped & (S["depth"] == 0)
            with dr.resume_grad(when=not primal):
                if lgroups:
                    sky, parts = lights.eval_groups(d, escaped, o, camera=seen, jitter=S.get("cjit"))
                    Le = S["β"] * mis * sky
                    for g in lgroups:
                        S[f"G:{g}"] = S[f"G:{g}"] + S["β"] * mis * parts[g]
                else:
                    Le = S["β"] * mis * lights.eval(d, escaped, o, camera=seen, jitter=S.get("cjit"))
            if aux:
                S["albedo"] = dr.select(seen, dr.clip(dr.detach(Le), 0.0, 1.0), S["albedo"])
            if primal:
                S["L"] = S["L"] + Le
            else:
                S["L"] = S["L"] - dr.detach(Le)
                with dr.resume_grad():
                    differentiate(S, Le)
            active = active & ~escaped

            # ---- a vertex: shade, sample a light (start its shadow ray) and a direction.  A symbolic
            # branch: a packet in which no lane stopped at a surface skips the shading code.
            S["active"] = active
            hit_args = (hit.valid, hit.t, hit.row, hit.tri, hit.part, hit.b1, hit.b2, d)
            out = dr.if_stmt(
                tuple(S[k] for k in keys) + hit_args,
                vertex,
                lambda *a: shade_vertex(dict(zip(keys, a[: len(keys)])), *a[len(keys) :]),
                lambda *a: a[: len(keys)],
                label="forest_path: vertex",
            )
            return tuple(out)

        def shade_vertex(
            S: dict[str, Any],
            h_valid: Any,
            h_t: Any,
            h_row: Any,
            h_tri: Any,
            h_part: Any,
            h_b1: Any,
            h_b2: Any,
            d: Any,
        ) -> tuple[Any, ...]:
            vertex = mi.Bool(True)
            hit = Hit(h_valid, h_t, h_row, h_tri, h_part, h_b1, h_b2)
            sp = surface(mi, self.scene, self.parts, hit, vertex)
            wi = -d
            flip = dr.dot(sp.n_sh, wi) < 0.0  # two-sided, as Mitsuba's ``twosided``
            ng = dr.select(flip, -sp.n_geo, sp.n_geo)
            ns = dr.select(flip, -sp.n_sh, sp.n_sh)
            with dr.resume_grad(when=not primal):
                sh = shading(
                    mi, self.mats, sp.material, sp.uv, sp.p, self.grid, self.extent, self.terrain_map, vertex,
                    h_row, self.row_tint, ns.y,
                )  # fmt: skip
                if water:  # a Fresnel mirror over the diffuse ground where the terrain is water
                    assert self.terrain_map is not None and self.water_ripple is not None
                    w = water_coverage(mi, self.mats, sp.material, sp.p, self.terrain_map, vertex)
                    wl = water_lobe(mi, sh, w, sp.p, wi, ng, self.water_ripple)
                    sh = wl.shading
            depth = S["depth"]
            if aux:
                first = depth == 0
                S["first"] = dr.select(first, h_row, S["first"])
                S["albedo"] = dr.select(first, dr.detach(sh.reflect + sh.transmit), S["albedo"])
                S["normal"] = dr.select(first, ns, S["normal"])
            nee = depth + 1 < self.max_depth
            u_pick = S["sampler"].next_1d(nee)
            u_dir = S["sampler"].next_2d(nee)
            dl, pdf_l = lights.sample_direction(u_pick, u_dir, nee)
            shd = sh.detached()
            f_l, pdf_b = bsdf_eval(shd, ns, dl, wi)
            nee &= (pdf_l > 0.0) & (dr.max(f_l) > 0.0)
            w_l = mis_weight(pdf_l, pdf_b) / dr.maximum(pdf_l, 1e-30)
            if lgroups:
                Ll, parts = lights.eval_groups(dl, nee, sp.p)
                S["C"] = dr.select(nee, S["β"] * f_l * Ll * w_l, S["C"])
                for g in lgroups:
                    S[f"C:{g}"] = dr.select(nee, S["β"] * f_l * parts[g] * w_l, S[f"C:{g}"])
            else:
                S["C"] = dr.select(nee, S["β"] * f_l * lights.eval(dl, nee, sp.p) * w_l, S["C"])
            u_lobe = S["sampler"].next_1d()
            u_bsdf = S["sampler"].next_2d()
            spec = mi.Bool(False)
            if water:  # the mirror with probability p (a delta lobe), else the diffuse part with u_lobe − p
                spec = u_lobe < wl.p
                u_lobe = dr.select(spec, 0.0, u_lobe - wl.p)
            wo, weight, pdf_o = bsdf_sample(mi, shd, mi.Frame3f(ns), u_lobe, u_bsdf, wi)
            if water:
                wo = dr.select(spec, wl.wo, wo)
                weight = dr.select(spec, mi.Color3f(wl.weight), weight)
                pdf_o = dr.select(spec, 1.0, pdf_o)
            cont = (depth + 1 < self.max_depth) & (pdf_o > 0.0)
            β_vertex = S["β"]
            β = S["β"] * dr.select(cont, weight, 0.0)
            β_max = dr.max(β)
            cont &= β_max > 0.0
            q = dr.minimum(β_max, 0.95)
            rr = depth >= self.rr_depth
            u_rr = S["sampler"].next_1d()
            β = dr.select(rr, β / dr.maximum(q, 1e-12), β)
            cont &= ~rr | (u_rr < q)
            if not primal:
                # No shadow ray pending: this vertex's path derivative can be taken now.
                with dr.resume_grad():
                    f_o, _ = bsdf_eval(sh, ns, wo, wi)
                    Lr_ind = S["L"] * dr.select(~nee & cont & ~spec, dr.relative_grad(f_o), 0.0)
                    differentiate(S, Lr_ind)
                for k, v in (("vp", sp.p), ("vuv", sp.uv), ("vmat", sp.material), ("vns", ns),
                             ("vwo", wo), ("vdl", dl), ("vβ", β_vertex), ("vw", w_l)):  # fmt: skip
                    S[k] = dr.select(nee, v, S[k])
                if "vwi" in S:
                    S["vwi"] = dr.select(nee, wi, S["vwi"])
                if "vrow" in S:
                    S["vrow"] = dr.select(nee, h_row, S["vrow"])
                if water:
                    S["vkeep"] = dr.select(nee, wl.keep, S["vkeep"])
                    S["vspec"] = dr.select(nee, spec, S["vspec"])
            S["β"] = β
            S["cont"] = cont
            S["eo"] = dr.select(cont, self.offset(sp.p, ng, wo), S["eo"])
            S["ed"] = dr.select(cont, wo, S["ed"])
            S["emaxt"] = dr.select(cont, dr.inf, S["emaxt"])
            S["eskips"] = dr.select(cont, 0, S["eskips"])
            S["shadowing"] = S["shadowing"] | nee
            S["so"] = dr.select(nee, self.offset(sp.p, ng, dl), S["so"])
            S["sd"] = dr.select(nee, dl, S["sd"])
            S["vis"] = dr.select(nee, 1.0, S["vis"])
            S["sskips"] = dr.select(nee, 0, S["sskips"])
            S["prev_pdf"] = pdf_o
            S["prev_delta"] = spec if water else mi.Bool(False)
            S["depth"] = depth + 1
            S["active"] = cont | nee
            return tuple(S[k] for k in keys)

        out = dict(zip(keys, dr.while_loop(tuple(state.values()), cond, body, label="forest_path: segments")))
        L = out["L"]
        if aux:
            first = {"row": out["first"], "albedo": out["albedo"], "normal": out["normal"], "segments": out["segments"]}
            split = {k[2:]: v for k, v in out.items() if k.startswith("G:")}
            if split:
                first["groups"] = split
            return L, out["covered"], L, first
        return (L if primal else out["δL"]), out["covered"], L

    def _shadow_step(
        self, on: Any, vis: Any, skips: Any, origin: Any, o: Any, d: Any, hit: Hit, alpha: Any
    ) -> tuple[Any, Any, Any, Any]:
        """One segment of a shadow chain on the lanes ``on``: the visibility times (1 − α) of a cut-out surface
        hit (0 past :data:`MAX_SKIPS` of them), whether the chain is done (it left the scene or is black), and
        its next origin just past the hit; returns (vis, skips, done, origin)."""
        import drjit as dr

        s_hit = on & hit.valid
        vis = dr.select(s_hit, vis * (1.0 - alpha), vis)
        skips = dr.select(s_hit, skips + 1, skips)
        vis = dr.select(s_hit & (skips >= MAX_SKIPS), 0.0, vis)
        done = on & (~hit.valid | (vis <= 0.0))
        origin = dr.select(on & ~done, dr.fma(d, self._past(o, d, hit.t), o), origin)
        return vis, skips, done, origin

    def _haze_step(
        self,
        S: dict[str, Any],
        haze: HazeModel,
        o: Any,
        d: Any,
        hit: Hit,
        ext: Any,
        primal: bool,
        differentiate: Callable[[dict[str, Any], Any], None],
        shafts: bool = False,
    ) -> None:
        """The haze along this step of an extension segment (see :mod:`.haze`), in place on the state ``S``.

        The step runs to the surface hit (a cut-out texel passed or the vertex), or — for a camera
        ray that leaves the scene — to the haze's sky distance.  Bounce rays that reach the sky
        are not hazed (the lights are the light arriving at the ground).  With ``shafts`` (primal
        only) a camera step adds the ambient share now and offers its sun share to the ray's
        reservoir (the module docstring, "light shafts").
        """
        import drjit as dr

        seg = ext & (hit.valid | (S["depth"] == 0))
        length = dr.select(hit.valid, hit.t, dr.minimum(S["emaxt"], haze.sky_distance))
        length = dr.select(seg, length, 0.0)
        if shafts:
            top = haze.fog_top(o, d, length) if haze.fog is not None else None  # read once, for T and the draw
            T = dr.exp(-haze.optical_depth(o, d, length, top))
            camera = seg & (S["depth"] == 0)
            scatter = S["β"] * (1.0 - T)
            c = dr.select(camera, scatter * haze.sun_source(d), 0.0)
            w = (c[0] + c[1] + c[2]) * (1.0 / 3.0)
            offer = camera & (w > 0.0)
            u_s = S["rng"].next_float32()
            u_keep = S["rng"].next_float32()
            t = haze.sample_distance(o, d, length, T, u_s, top)
            t = dr.minimum(t, length * 0.999)  # a point in the air, short of the surface the step ends on
            hw = S["hw"] + dr.select(offer, w, 0.0)
            keep = offer & (u_keep * hw < w)
            S["hw"] = hw
            S["hx"] = dr.select(keep, dr.fma(d, t, o), S["hx"])
            S["hc"] = dr.select(keep, c / dr.maximum(w, 1e-30), S["hc"])
            C = dr.select(seg, scatter * dr.select(camera, haze.ambient(), haze.source(d)), 0.0)
            S["L"] = S["L"] + C
            if "G:haze" in S:
                S["G:haze"] = S["G:haze"] + C
            S["β"] = S["β"] * dr.select(seg, T, 1.0)
            return
        with dr.resume_grad(when=not primal):
            T = haze.transmittance(o, d, length)
            C = dr.select(seg, S["β"] * (1.0 - T) * haze.source(d), 0.0)
        if primal:
            S["L"] = S["L"] + C
            if "G:haze" in S:
                S["G:haze"] = S["G:haze"] + C
        else:
            L = S["L"] - dr.detach(C)
            with dr.resume_grad():
                differentiate(S, C + L * dr.select(seg, dr.relative_grad(T), 0.0))
            S["L"] = L
        S["β"] = S["β"] * dr.detach(dr.select(seg, T, 1.0))


_CLASSES: dict[str, type] = {}


def integrator_class(mi: Any) -> type:
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
        def __init__(self, props: Any) -> None:
            super().__init__(props)  # type: ignore[no-untyped-call]  # Mitsuba's RBIntegrator.__init__ is unannotated
            self.kernel: PathKernel | None = None

        def bind(self, kernel: PathKernel) -> ForestPathIntegrator:
            self.kernel = kernel
            self.max_depth = kernel.max_depth
            return self

        # RBIntegrator.sample's signature; the kernel holds the scene.  Mitsuba passes every argument by keyword,
        # depth and δaovs too (taken by **kwargs).  The override is not one mypy accepts, and cannot be: Mitsuba's
        # own type annotations already make RBIntegrator.sample incompatible with SamplingIntegrator.sample.
        def sample(  # type: ignore[override]
            self,
            mode: Any,
            scene: Any,  # noqa: ARG002
            sampler: Any,
            ray: Any,
            δL: Any,
            state_in: Any,
            active: Any,
            **kwargs: Any,  # noqa: ARG002
        ) -> tuple[Any, Any, list[Any], Any]:
            if self.kernel is None:
                raise RuntimeError("forest_path: bind the integrator to a PathKernel first (PathScene.integrator())")
            L, valid, state = self.kernel.sample(mode, sampler, ray, δL, state_in, active)
            return L, valid, [], state

        def aov_names(self) -> list[str]:
            return []

        def to_string(self) -> str:
            return "ForestPathIntegrator[]"

    mi.register_integrator("forest_path", lambda props: ForestPathIntegrator(props))
    _CLASSES[variant] = ForestPathIntegrator
    return ForestPathIntegrator
