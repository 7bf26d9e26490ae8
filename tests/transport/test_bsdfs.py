"""BSDFs against their own pdfs and closed forms.

- Sampling agrees with ``pdf``: a chi-square test over the sphere of directions (as pbrt's and
  Mitsuba's BSDF tests do), bins uniform in (cos theta, phi), expected counts integrated from
  ``pdf`` on a fine grid, for every non-delta material at several roughnesses and incident angles.
- Sampling agrees with ``eval``: a sample's weight is ``eval / pdf`` and its pdf ``pdf(wi)``.
- GGX energy at normal incidence matches a quadrature of the microfacet formula written out here
  independently (docs/closed_forms.md#ggx): 0.916 at alpha 0.25, below the bound
  ``1 - alpha^2 / (1 + alpha^2)`` set by the normals that reflect below the horizon.
- Fresnel at normal incidence is ((n - 1)/(n + 1))^2, refraction obeys Snell's law, total internal
  reflection reflects everything (docs/closed_forms.md#fresnel).
"""

from __future__ import annotations

import math

import pytest
import torch

from invrender.plugins.bsdfs.checks import chi_square_p, local_directions, shading_point
from invrender.plugins.bsdfs.dielectric import Dielectric, fresnel_dielectric
from invrender.plugins.bsdfs.diffuse import Diffuse
from invrender.plugins.bsdfs.glossy import Glossy
from invrender.plugins.bsdfs.mirror import Mirror

KS = torch.tensor([0.9, 0.7, 0.5])


def diffuse():
    return Diffuse([{"reflectance": torch.tensor([0.8, 0.5, 0.2])}], [{}])


def glossy(alpha: float):
    return Glossy([{"specular_reflectance": KS, "roughness": torch.full((3,), float(alpha))}], [{}])


@pytest.mark.parametrize("theta_o", [0.0, 0.7, 1.4])
def test_diffuse_sampling_matches_pdf(theta_o):
    assert chi_square_p(diffuse(), theta_o) > 1e-3


@pytest.mark.parametrize("alpha", [0.05, 0.25, 0.6, 1.0])
@pytest.mark.parametrize("theta_o", [0.0, 0.8, 1.35])
def test_glossy_sampling_matches_pdf(alpha, theta_o):
    assert chi_square_p(glossy(alpha), theta_o, seed=int(alpha * 100) + int(theta_o * 10)) > 1e-3


def test_chi_square_catches_a_wrong_pdf():
    """The test has power: a GGX sampler checked against the pdf of another roughness fails."""

    class Mismatched(Glossy):
        def pdf(self, sp, wi):
            return glossy(0.3).pdf(sp, wi)

    assert chi_square_p(Mismatched([{"specular_reflectance": KS, "roughness": torch.full((3,), 0.25)}], [{}]), 0.5) < 1e-6


@pytest.mark.parametrize("bsdf", [diffuse(), glossy(0.1), glossy(0.5), glossy(1.0)], ids=["diffuse", "ggx0.1", "ggx0.5", "ggx1"])
@pytest.mark.parametrize("theta_o", [0.2, 1.0])
def test_sample_weight_is_eval_over_pdf(bsdf, theta_o):
    g = torch.Generator().manual_seed(3)
    n = 4096
    sp = shading_point(theta_o, n, normal=(0.3, -0.5, 0.8))
    bs = bsdf.sample(sp, torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    ok = bs.pdf > 1e-3
    assert ok.float().mean() > 0.5
    torch.testing.assert_close(bs.pdf[ok], bsdf.pdf(sp, bs.wi)[ok], rtol=2e-3, atol=1e-5)
    torch.testing.assert_close(bs.weight[ok], bsdf.eval(sp, bs.wi)[ok] / bs.pdf[ok, None], rtol=2e-3, atol=1e-5)


def test_diffuse_weight_is_rho_and_pdf_integrates_to_one():
    sp = shading_point(0.5, 1000)
    bs = diffuse().sample(sp, torch.rand(1000), torch.rand(1000, 2))
    torch.testing.assert_close(bs.weight, torch.tensor([0.8, 0.5, 0.2]).expand(1000, 3))


def ggx_albedo_quadrature(alpha: float, n: int = 2000) -> float:
    """int f cos dw at normal incidence, f = D G1(wo) G1(wi) / (4 cos_o cos_i), written out here:
    wo = +z, so h bisects z and wi and cos_o = 1, G1(wo) = 1."""
    mu = (torch.arange(n, dtype=torch.float64) + 0.5) / n  # cos theta_i, midpoint rule
    cos_h = ((1 + mu) / 2).sqrt()  # half vector between +z and wi
    a2 = alpha * alpha
    D = a2 / (math.pi * (cos_h**2 * (a2 - 1) + 1) ** 2)
    tan2 = (1 - mu * mu) / (mu * mu)
    G1_i = 2 / (1 + (1 + a2 * tan2).sqrt())
    f_cos = D * G1_i / 4  # (D G / (4 cos_o cos_i)) cos_i, cos_o = 1
    return float((f_cos * 2 * math.pi).sum() / n)  # azimuth integrates to 2 pi


@pytest.mark.parametrize("alpha", [0.1, 0.25, 0.5, 1.0])
def test_ggx_energy_at_normal_incidence(alpha):
    """Directional albedo: the Monte Carlo mean of sample weights and a quadrature of ``eval`` both
    match the independent quadrature of the formula; below 1 (single scattering loses energy) and
    falling with roughness."""
    reference = ggx_albedo_quadrature(alpha)
    n = 400_000
    g = torch.Generator().manual_seed(7)
    sp = shading_point(0.0, n)
    bs = glossy(alpha).sample(sp, torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    mc = float(bs.weight[:, 0].double().mean() / KS[0])
    assert abs(mc - reference) < 3e-3 * reference
    # eval integrated over the hemisphere on a grid (cos theta, phi)
    m = 600
    C, P = torch.meshgrid((torch.arange(m, dtype=torch.float64) + 0.5) / m, (torch.arange(64, dtype=torch.float64) + 0.5) * (2 * math.pi / 64), indexing="ij")
    d = local_directions(C, P).reshape(-1, 3).float()
    quad = float(glossy(alpha).eval(shading_point(0.0, d.shape[0]), d)[:, 0].double().sum() * (1 / m) * (2 * math.pi / 64) / KS[0])
    assert abs(quad - reference) < 3e-3 * reference
    # single scattering loses energy: at normal incidence the microfacets tilted beyond 45 degrees
    # (GGX mass alpha^2 / (1 + alpha^2) of D(h) cos_h) send the light below the horizon, and the
    # masking G1(wi) removes more
    assert reference < 1.0 - alpha**2 / (1 + alpha**2)


def test_fresnel_closed_forms():
    for n in (1.33, 1.5, 2.4):
        F, cos_t = fresnel_dielectric(torch.tensor([1.0]), torch.tensor([n]))
        assert abs(float(F) - ((n - 1) / (n + 1)) ** 2) < 1e-6
        assert abs(float(cos_t) - 1.0) < 1e-6
    # leaving glass beyond the critical angle asin(1/1.5) = 41.8 degrees: total internal reflection
    F, _ = fresnel_dielectric(torch.tensor([math.cos(math.radians(50))]), torch.tensor([1 / 1.5]))
    assert float(F) == 1.0
    # Brewster's angle atan(1.5): r_p = 0, so F = r_s^2 / 2
    ci = math.cos(math.atan(1.5))
    F, ct = fresnel_dielectric(torch.tensor([ci]), torch.tensor([1.5]))
    rs = (ci - 1.5 * float(ct)) / (ci + 1.5 * float(ct))
    assert abs(float(F) - rs * rs / 2) < 1e-6


@pytest.mark.parametrize("front", [True, False])
def test_dielectric_refraction_obeys_snell_and_splits_by_fresnel(front):
    theta = 0.5 if front else 0.3
    n = 20000
    sp = shading_point(theta, n, front=front)
    bsdf = Dielectric([{}], [{"ior": 1.5}])
    eta = 1.5 if front else 1 / 1.5
    (wr, w_r), (wt, w_t) = bsdf.specular_lobes(sp)
    # reflection mirrors wo; refraction: sin_t = sin_i / eta, on the other side
    torch.testing.assert_close(wr[0], torch.tensor([-sp.wo[0, 0], -sp.wo[0, 1], sp.wo[0, 2]]), atol=1e-6, rtol=0)
    assert float(wt[0, 2]) < 0
    sin_t = float((1 - wt[0, 2] ** 2).sqrt())
    assert abs(sin_t - math.sin(theta) / eta) < 1e-5
    F, _ = fresnel_dielectric(torch.tensor([math.cos(theta)]), torch.tensor([eta]))
    torch.testing.assert_close(w_r[0], float(F) * torch.ones(3))
    torch.testing.assert_close(w_t[0], (1 - float(F)) / eta**2 * torch.ones(3))
    # sampling picks reflection with probability F, weight 1; refraction weight 1 / eta^2
    bs = bsdf.sample(sp, torch.rand(n, generator=torch.Generator().manual_seed(1)), torch.rand(n, 2))
    reflected = bs.wi[:, 2] > 0
    assert abs(float(reflected.float().mean()) - float(F)) < 4 * math.sqrt(float(F) * (1 - float(F)) / n)
    assert bool(bs.delta.all()) and float(bs.pdf.abs().max()) == 0
    torch.testing.assert_close(bs.weight[~reflected], torch.full_like(bs.weight[~reflected], 1 / eta**2))


def test_mirror_reflects_with_specular_reflectance():
    sp = shading_point(0.6, 5, normal=(0.2, 0.3, 0.9))
    bsdf = Mirror([{"specular_reflectance": KS}], [{}])
    bs = bsdf.sample(sp, torch.rand(5), torch.rand(5, 2))
    n = sp.n[0]
    expected = 2 * torch.dot(sp.wo[0], n) * n - sp.wo[0]
    torch.testing.assert_close(bs.wi[0], expected)
    torch.testing.assert_close(bs.weight, KS.expand(5, 3))
    assert float(bsdf.eval(sp, bs.wi).abs().max()) == 0 and bool(bs.delta.all())
