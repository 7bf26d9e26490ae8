"""Cook's distribution ray tracing (Cook, Porter and Carpenter 1984), as Kajiya's lecture writes it:

    I = (1/Omega) int k_s L_sp dw  +  k_d int cos cos L_e / r^2 dA  +  k_a L_a

- the specular term: the glossy lobe is sampled and followed recursively (blurry reflections; a
  mirror's or glass's delta lobes are followed as Whitted does), and emitters it reaches count;
- the diffuse term: soft shadows, direct light from area emitters estimated by sampling points on
  them (at glossy vertices combined with the followed lobe by MIS);
- the ambient term ``k_a L_a``: ``rho eps0`` at diffuse vertices, the stand-in for diffuse
  interreflection, which the model leaves out: a path ends at its first diffuse vertex.

Antialiasing (jittered pixel samples) and depth of field (the thin-lens camera) come from the
driver's camera rays. It is the path tracer with diffuse vertices ending after their direct light;
Russian roulette as in the path tracer. Differentiable in rho, k_s, eps and eps0. Which vertices
count as diffuse is asked of the BSDF's lobe flags: any BSDF with a diffuse lobe ends the path there
(a layered material's coating then reflects direct light but is not followed).
"""

from __future__ import annotations

from invrender.core.bsdfs import Lobe
from invrender.plugins.integrators.path import Path
from invrender.plugins.integrators.vertex import add_ambient, add_direct


class Distributed(Path):
    name = "distributed"
    summary = "Cook's distribution ray tracing: glossy lobes followed, soft shadows, ambient k_a*eps0"

    def at_vertex(self, ctx, state, s, sp, u, depth, film):
        diffuse = ctx.materials.has(sp, Lobe.DIFFUSE)
        d = diffuse.nonzero()[:, 0]
        if d.numel():
            # k_d int cos cos L_e / r^2 dA + k_a L_a, into term depth + 1; the path ends here
            ds, dsp = state.select(d), sp.select(d)
            add_direct(ctx, ds, s.select(d), dsp, u.index_select(0, d), depth + 1, film, mis=False)
            add_ambient(ctx, ds, dsp, depth + 1, film)
        g = (~diffuse).nonzero()[:, 0]
        if g.numel():
            # glossy vertices: direct light with MIS against the lobe followed next (delta ones skip it)
            add_direct(ctx, state.select(g), s.select(g), sp.select(g), u.index_select(0, g), depth + 1, film, mis=True)
        return g
