"""Statistical checks of an environment emitter's direction sampling (the analogue of
:mod:`invrender.plugins.bsdfs.checks` for BSDFs): its ``sample_from`` directions against its
``pdf_escaped``, by a chi-square test on a (theta, phi) histogram about +Y, and the integral of the
pdf over the sphere. Used by the tests; cheap enough to run on any map.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

from invrender.core.lights import Light


def _grid(nt: int, nphi: int, st: int, sph: int):
    """Midpoints (M, 3) of an (nt * st) x (nphi * sph) grid in (theta about +Y, phi = atan2(x, -z))
    and their solid angles (M,) float64."""
    dt, dp = math.pi / (nt * st), 2 * math.pi / (nphi * sph)
    t = (torch.arange(nt * st, dtype=torch.float64) + 0.5) * dt
    p = (torch.arange(nphi * sph, dtype=torch.float64) + 0.5) * dp
    T, P = torch.meshgrid(t, p, indexing="ij")
    d = torch.stack([torch.sin(T) * torch.sin(P), torch.cos(T), -torch.sin(T) * torch.cos(P)], dim=-1).reshape(-1, 3)
    return d, (torch.sin(T) * dt * dp).reshape(-1)


def pdf_integral(light: Light, bins=(256, 512), pdf: Callable | None = None) -> float:
    """The integral over the sphere of ``light.pdf_escaped`` (or ``pdf``) by the midpoint rule."""
    pdf = light.pdf_escaped if pdf is None else pdf
    d, cell = _grid(bins[0], bins[1], 1, 1)
    return float((pdf(d.float()).double() * cell).sum())


def chi_square_p(light: Light, samples: int = 200_000, bins=(20, 40), sub=(16, 16), seed: int = 0, pdf: Callable | None = None) -> float:
    """p-value of the chi-square test of ``light.sample_from``'s directions against
    ``light.pdf_escaped`` (or ``pdf``, to show the test's power); bins uniform in (theta about +Y,
    phi), expected counts from the pdf by the midpoint rule on sub-cells (``dw = sin theta dtheta
    dphi``), bins expected to hold fewer than 5 samples pooled."""
    pdf = light.pdf_escaped if pdf is None else pdf
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(samples, 3, generator=g)
    x = torch.zeros(samples, 3)
    n = torch.tensor([0.0, 1.0, 0.0]).expand(samples, 3)
    ls = light.sample_from(u, x, n, 0.0)
    wl = ls.wl.double()
    valid = ls.pdf > 0
    nt, nphi = bins
    it = (torch.acos(wl[:, 1].clamp(-1, 1)) / math.pi * nt).long().clamp(0, nt - 1)
    ip = ((torch.atan2(wl[:, 0], -wl[:, 2]) % (2 * math.pi)) / (2 * math.pi) * nphi).long().clamp(0, nphi - 1)
    observed = torch.zeros(nt * nphi + 1, dtype=torch.float64)
    observed.index_add_(0, torch.where(valid, it * nphi + ip, nt * nphi), torch.ones(samples, dtype=torch.float64))
    d, cell = _grid(nt, nphi, *sub)
    density = (pdf(d.float()).double() * cell).reshape(nt, sub[0], nphi, sub[1]).sum((1, 3))
    expected = torch.cat([density.reshape(-1), (1 - density.sum()).clamp_min(0).reshape(1)]) * samples
    low = expected < 5
    obs = torch.cat([observed[~low], observed[low].sum().reshape(1)])
    exp = torch.cat([expected[~low], expected[low].sum().reshape(1)])
    keep = exp > 0
    if float(obs[~keep].sum()) > 0:
        return 0.0  # samples where the pdf is zero
    chi2 = float(((obs[keep] - exp[keep]) ** 2 / exp[keep]).sum())
    dof = int(keep.sum()) - 1
    return float(torch.special.gammaincc(torch.tensor(dof / 2, dtype=torch.float64), torch.tensor(chi2 / 2, dtype=torch.float64)))
