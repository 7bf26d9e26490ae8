"""Conformance checks for BSDF plugins, the ones every registered material must pass (as Mitsuba's
``chi2`` module and pbrt's ``bsdftest`` check theirs): run by the test suite over the whole
registry, and callable by anyone writing a material of their own.

- :func:`chi_square_p`: sampling agrees with ``pdf`` (a chi-square test over the sphere of
  directions, bins uniform in (theta, phi), expected counts integrated from ``pdf`` on a fine grid).
- :func:`weight_errors`: a smooth sample's weight is ``eval / pdf`` and its pdf ``pdf(wi)``.
- :func:`delta_weight_gap`: delta samples, averaged over the lobe choice, carry the weights that
  :meth:`~invrender.core.bsdfs.BSDF.specular_lobes` lists.

All work on points with normal +z (or a given normal) and ``wo`` at a given angle from it.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from invrender.core.bsdfs import BSDF, ShadingPoint


def instance(cls: type[BSDF], **entries) -> BSDF:
    """One material of type ``cls`` at its declared defaults (``entries`` override parameters or
    constants), as a render would build it."""
    values = {k: torch.as_tensor(entries.get(k, p.default), dtype=torch.float32).expand(3).clone() for k, p in cls.params.items()}
    constants = {k: (tuple(float(x) for x in v) if c.size > 1 else float(v)) for k, c in cls.constants.items() for v in [entries.get(k, c.default)]}
    return cls([values], [constants])


def shading_point(theta_o: float, n: int, normal=(0.0, 0.0, 1.0), front: bool = True) -> ShadingPoint:
    """``n`` identical points with normal ``normal`` and wo at ``theta_o`` from it (in the xz plane)."""
    nrm = torch.tensor(normal, dtype=torch.float32)
    nrm = nrm / nrm.norm()
    # a tangent orthogonal to the normal, to tilt wo by theta_o
    t = torch.linalg.cross(nrm, torch.tensor([0.0, 1.0, 0.0]) if abs(float(nrm[1])) < 0.9 else torch.tensor([1.0, 0.0, 0.0]))
    t = t / t.norm()
    wo = math.cos(theta_o) * nrm + math.sin(theta_o) * t
    rows = lambda v: v.expand(n, 3).clone()  # noqa: E731
    zeros = torch.zeros(n, dtype=torch.int64)
    return ShadingPoint(rows(wo), rows(nrm), rows(nrm), torch.full((n,), front), torch.zeros(n, 2), zeros, zeros)


def local_directions(cos_t: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    s = (1 - cos_t * cos_t).clamp_min(0).sqrt()
    return torch.stack([s * torch.cos(phi), s * torch.sin(phi), cos_t], dim=-1)


def chi_square_p(bsdf, theta_o: float, samples: int = 200_000, bins=(20, 40), sub=(48, 32), seed: int = 0, front: bool = True) -> float:
    """p-value of the chi-square test of ``bsdf.sample`` against ``bsdf.pdf`` (normal +z, ``wo``
    outside or, ``front`` False, inside); bins uniform in (theta, phi), expected counts from the
    pdf by Gauss-Legendre nodes in theta and the midpoint rule in phi (``dw = sin theta dtheta
    dphi``)."""
    g = torch.Generator().manual_seed(seed)
    sp = shading_point(theta_o, samples, front=front)
    bs = bsdf.sample(sp, torch.rand(samples, generator=g), torch.rand(samples, 2, generator=g))
    wi = bs.wi.double()
    valid = (bs.weight.amax(1) > 0) & ~bs.delta  # delta samples fall in the pdf's missing mass
    nt, nphi = bins
    st, sph = sub
    it = (torch.acos(wi[:, 2].clamp(-1, 1)) / math.pi * nt).long().clamp(0, nt - 1)
    ip = ((torch.atan2(wi[:, 1], wi[:, 0]) % (2 * math.pi)) / (2 * math.pi) * nphi).long().clamp(0, nphi - 1)
    observed = torch.zeros(nt * nphi + 1, dtype=torch.float64)
    observed.index_add_(0, torch.where(valid, it * nphi + ip, nt * nphi), torch.ones(samples, dtype=torch.float64))
    # expected counts: pdf integrated over each bin, in theta by an st-point Gauss-Legendre rule
    # per bin (exact enough for lobes as narrow as a few of its nodes, e.g. rough glass's refracted
    # peak at a pole), in phi by the midpoint rule on sph sub-cells
    x, w = np.polynomial.legendre.leggauss(st)
    bt = math.pi / nt
    t = ((torch.arange(nt, dtype=torch.float64)[:, None] + torch.from_numpy(0.5 * (x + 1.0))[None]) * bt).reshape(-1)
    wt = (torch.from_numpy(0.5 * w * bt)[None].expand(nt, st)).reshape(-1)
    dp = 2 * math.pi / (nphi * sph)
    p = (torch.arange(nphi * sph, dtype=torch.float64) + 0.5) * dp
    T, P = torch.meshgrid(t, p, indexing="ij")
    d = local_directions(torch.cos(T), P).reshape(-1, 3).float()
    spg = shading_point(theta_o, d.shape[0], front=front)
    cell = (torch.sin(T) * wt[:, None] * dp).reshape(-1)
    density = (bsdf.pdf(spg, d).double() * cell).reshape(nt, st, nphi, sph).sum((1, 3))
    expected = torch.cat([density.reshape(-1), (1 - density.sum()).clamp_min(0).reshape(1)]) * samples
    # pool bins expected to hold fewer than 5 samples (the test's usual rule)
    low = expected < 5
    obs = torch.cat([observed[~low], observed[low].sum().reshape(1)])
    exp = torch.cat([expected[~low], expected[low].sum().reshape(1)])
    keep = exp > 0
    assert obs[~keep].sum() == 0, "samples fell where the pdf is zero"
    chi2 = float(((obs[keep] - exp[keep]) ** 2 / exp[keep]).sum())
    dof = int(keep.sum()) - 1
    return float(torch.special.gammaincc(torch.tensor(dof / 2, dtype=torch.float64), torch.tensor(chi2 / 2, dtype=torch.float64)))


def weight_errors(bsdf: BSDF, theta_o: float, n: int = 4096, normal=(0.3, -0.5, 0.8), seed: int = 3, front: bool = True) -> tuple[float, float, float]:
    """(largest relative error of ``pdf`` against ``pdf(wi)``, of ``weight`` against
    ``eval / pdf``, the fraction of smooth samples checked) over the smooth samples of ``n``
    (``wo`` outside or, ``front`` False, inside)."""
    g = torch.Generator().manual_seed(seed)
    sp = shading_point(theta_o, n, normal=normal, front=front)
    bs = bsdf.sample(sp, torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    ok = (bs.pdf > 1e-3) & ~bs.delta
    if not bool(ok.any()):
        return 0.0, 0.0, 0.0
    pdf = bsdf.pdf(sp, bs.wi)[ok]
    expected = bsdf.eval(sp, bs.wi)[ok] / bs.pdf[ok, None]
    pdf_err = float(((bs.pdf[ok] - pdf).abs() / (pdf.abs() + 1e-5)).max())
    weight_err = float(((bs.weight[ok] - expected).abs() / (expected.abs() + 1e-5)).max())
    return pdf_err, weight_err, float(ok.float().mean())


def delta_weight_gap(bsdf: BSDF, theta_o: float, n: int = 200_000, seed: int = 5) -> float:
    """Largest difference, per lobe and channel, between the mean weight of the delta samples
    that took a lobe's direction (over all ``n`` samples, so the lobe choice is averaged out) and
    the weight :meth:`~invrender.core.bsdfs.BSDF.specular_lobes` gives that lobe."""
    g = torch.Generator().manual_seed(seed)
    sp = shading_point(theta_o, n)
    bs = bsdf.sample(sp, torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    gap = 0.0
    for wi, weight in bsdf.specular_lobes(sp):
        took = bs.delta & ((bs.wi - wi).abs().amax(1) < 1e-4)
        mean = (bs.weight * took[:, None]).double().mean(0)
        gap = max(gap, float((mean - weight[0].double()).abs().max()))
    return gap
