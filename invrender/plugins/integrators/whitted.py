"""Whitted's recursive ray tracing (Whitted 1980), as a truncation of the Neumann series.

At a vertex whose BSDF has a smooth (diffuse or glossy) lobe the local model ends that part of the
path: direct light from the emitters (a shadow ray to a point sampled on an area emitter) plus the
ambient term ``k_d eps0``. Every delta lobe is followed: at a mirror the reflected ray; at glass the
path splits, as Whitted's did, into the reflected ray weighted by the Fresnel reflectance F and the
refracted ray weighted by ``(1 - F) / eta^2``, both followed recursively up to ``max_depth`` terms.
A BSDF with both kinds (a diffuse base under a smooth coating) gets both. The lobes are asked of
the BSDF's flags, never of its type. No roulette and no random choice between lobes, so
with emitters seen only through delta chains the image has no noise at all. Differentiable in rho,
k_s, eps and eps0; path replay gives each branch a film index of its own (``film.branch``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.errors import ParameterError
from invrender.core.bsdfs import BSDFSample, Lobe
from invrender.core.context import PathState, TransportContext
from invrender.core.film import Film
from invrender.plugins.integrators.base import DepthSettings, Integrator
from invrender.plugins.integrators.random_walk import DIMS
from invrender.plugins.integrators.vertex import absorbed, add_ambient, add_direct, add_emitted, next_vertex, scattered
from invrender.core.sampler import branch_keys, uniform


@dataclass(frozen=True)
class WhittedSettings(DepthSettings):
    """Settings of Whitted ray tracing.

    Attributes:
        max_depth: Neumann terms kept, >= 1 (no -1: without roulette an unbounded split tree
            would not end).
    """

    def __post_init__(self):
        super().__post_init__()
        if self.max_depth < 1:
            raise ParameterError(f"whitted needs a finite max_depth >= 1, got {self.max_depth}")


class Whitted(Integrator):
    name = "whitted"
    Settings = WhittedSettings
    summary = "Whitted ray tracing: direct light + ambient at diffuse vertices, mirrors and glass followed (split)"

    def trace(self, ctx: TransportContext, state: PathState, film: Film) -> None:
        cfg = self.settings
        depth = 0
        while state.count:
            state, s = next_vertex(ctx, state, film, depth)
            if s is None:
                break
            add_emitted(ctx, state, s, depth, film, mis=False)  # term depth: emitters seen (through delta chains)
            if not cfg.continues_after(depth):
                break
            sp = ctx.shading_point(s, -state.d)
            i = ctx.materials.has(sp, Lobe.SMOOTH).nonzero()[:, 0]
            if i.numel():
                # the local model: direct light and ambient into term depth + 1; the smooth lobes end here
                ls, lsp = state.select(i), sp.select(i)
                add_direct(ctx, ls, s.select(i), lsp, uniform(ls.keys, depth + 1, DIMS), depth + 1, film, mis=False)
                add_ambient(ctx, ls, lsp, depth + 1, film)
            i = ctx.materials.has(sp, Lobe.DELTA).nonzero()[:, 0]  # the delta lobes are followed
            state, s, sp = state.select(i), s.select(i), sp.select(i)
            children = []
            for bsdf, index in ctx.materials.groups(sp):
                if index is not None:
                    sub, sub_s, sub_sp = state.select(index), s.select(index), sp.select(index)
                else:
                    sub, sub_s, sub_sp = state, s, sp
                if not bsdf.has(Lobe.DELTA) or not sub.count:
                    continue
                lobes = bsdf.specular_lobes(sub_sp)
                for k, (wi, weight) in enumerate(lobes):
                    # a split gives each branch its own film index and random numbers
                    child = sub if len(lobes) == 1 else sub.replace(pixel=film.branch(sub.pixel), keys=branch_keys(sub.keys, k))
                    no_pdf = torch.zeros_like(child.pdf_dir)
                    sample = BSDFSample(wi, weight, no_pdf, torch.ones_like(child.delta))
                    child = scattered(ctx, child, sub_s, sample, film)
                    dead = absorbed(ctx, child)
                    children.append(child if dead is None else child.select(~dead))
            if not children:
                break
            state = PathState.cat(children)
            depth += 1
