"""Uniform hemisphere sampling of the diffuse BSDF against its own pdf and eval.

Uniform over the hemisphere of the normal means cos(theta) uniform on [0, 1) and phi uniform on
[0, 2 pi): a chi-square test on equal bins of (cos theta, phi); the pdf is 1/(2 pi) above the
surface and 0 below (so it integrates to 1), and a sample's weight is eval / pdf = 2 rho cos.
"""

from __future__ import annotations

import math

import torch

from invrender.core.bsdfs import BSDFSampling, ShadingPoint
from invrender.plugins.bsdfs.diffuse import Diffuse
from invrender.core.frame import Frame

RHO = torch.tensor([0.8, 0.5, 0.2])


def points(n: int, normal=(0.3, -0.5, 0.8)) -> ShadingPoint:
    nrm = torch.tensor(normal) / torch.tensor(normal).norm()
    wo = nrm  # at normal incidence; a diffuse lobe does not depend on wo
    zeros = torch.zeros(n, dtype=torch.int64)
    return ShadingPoint(wo.expand(n, 3).clone(), nrm.expand(n, 3).clone(), nrm.expand(n, 3).clone(), torch.ones(n, dtype=torch.bool), torch.zeros(n, 2), zeros, zeros)


def uniform_diffuse() -> Diffuse:
    return Diffuse([{"reflectance": RHO}], [{}], sampling=BSDFSampling("uniform"))


def draw(bsdf, n=100_000, seed=0):
    g = torch.Generator().manual_seed(seed)
    sp = points(n)
    return sp, bsdf.sample(sp, torch.rand(n, generator=g), torch.rand(n, 2, generator=g))


def test_uniform_directions_fill_the_hemisphere_evenly():
    sp, bs = draw(uniform_diffuse())
    local = Frame.from_normal(sp.n).to_local(bs.wi)
    cos_t, phi = local[:, 2], torch.atan2(local[:, 1], local[:, 0]) % (2 * math.pi)
    assert bool((cos_t >= 0).all())
    bins = (cos_t.clamp(0, 1 - 1e-7) * 10).long() * 20 + (phi / (2 * math.pi) * 20).long().clamp(max=19)
    counts = torch.bincount(bins, minlength=200).double()
    expected = cos_t.numel() / 200
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < 290  # 199 degrees of freedom: p ~ 1e-4 above this


def test_uniform_pdf_weight_and_eval_agree():
    bsdf = uniform_diffuse()
    sp, bs = draw(bsdf, n=4096)
    torch.testing.assert_close(bs.pdf, torch.full_like(bs.pdf, 1 / (2 * math.pi)))
    torch.testing.assert_close(bsdf.pdf(sp, bs.wi), bs.pdf)
    torch.testing.assert_close(bs.weight, bsdf.eval(sp, bs.wi) / bs.pdf[:, None], rtol=1e-4, atol=1e-6)
    cos_i = (sp.n * bs.wi).sum(1)
    torch.testing.assert_close(bs.weight, 2 * RHO * cos_i[:, None], rtol=1e-4, atol=1e-6)
    below = -bs.wi
    assert float(bsdf.pdf(sp, below).abs().max()) == 0.0


def test_uniform_pdf_integrates_to_one_and_the_mean_weight_is_rho():
    """Over directions uniform on the whole sphere, E[pdf] 4 pi = 1; E[weight] = rho (the albedo)."""
    bsdf = uniform_diffuse()
    g = torch.Generator().manual_seed(1)
    d = torch.randn(200_000, 3, generator=g)
    d = d / d.norm(dim=1, keepdim=True)
    assert abs(float(bsdf.pdf(points(d.shape[0]), d).mean()) * 4 * math.pi - 1) < 0.01
    _, bs = draw(bsdf)
    torch.testing.assert_close(bs.weight.mean(0), RHO, rtol=0.01, atol=0)


def test_cosine_remains_the_default():
    bsdf = Diffuse([{"reflectance": RHO}], [{}])
    sp, bs = draw(bsdf, n=1024)
    torch.testing.assert_close(bs.weight, RHO.expand(1024, 3))
    torch.testing.assert_close(bs.pdf, (sp.n * bs.wi).sum(1).clamp_min(0) / math.pi)
