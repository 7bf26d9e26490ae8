"""The older integrators of the ladder against independent estimators, where they must agree.

- Whitted, distributed and Utah at ``max_depth`` 2 on a diffuse scene with ambient radiance all
  compute ``g eps + g M g eps + rho eps0``: Utah by MIS of emitter and BSDF sampling, Whitted and
  distributed by emitter sampling alone (soft shadows).
- Whitted equals the path tracer on a scene whose diffuse surfaces are black: all light reaches the
  camera through chains of mirror and glass, which Whitted follows deterministically (splitting at
  glass by Fresnel) and the path tracer by sampling one branch with probability F.
- Distributed equals the path tracer on a scene whose diffuse surfaces are black: the glossy lobe
  is followed as the path tracer follows it, and diffuse vertices (which end distributed paths)
  contribute nothing to either.

Means are compared with their Monte Carlo standard errors: each pair of renders shares its seed,
so their camera rays (and the emitters they see directly) are the same and only the estimators of
the later terms differ; the standard error is that of the paired differences over several seeds.
"""

from __future__ import annotations

import math

import torch

import invrender as ir


def paired(scene, a, b, seeds, kw_a=None, kw_b=None, **kw):
    """Channel means (3,) of render ``a``, and the mean (3,) and standard error (3,) of the
    differences ``a - b`` of channel means over renders sharing a seed."""
    ma, diffs = [], []
    for s in seeds:
        ia = ir.render(scene, a, seed=s, progress=False, **kw, **(kw_a or {})).double().mean((0, 1))
        ib = ir.render(scene, b, seed=s, progress=False, **kw, **(kw_b or {})).double().mean((0, 1))
        ma.append(ia)
        diffs.append(ia - ib)
    d = torch.stack(diffs)
    return torch.stack(ma).mean(0), d.mean(0), d.std(0) / math.sqrt(len(seeds))


def assert_agree(scene, a, b, seeds, k=4.0, **kw):
    mean, diff, se = paired(scene, a, b, seeds, **kw)
    assert float(mean.min()) > 0.01  # light reaches the camera through what is compared
    assert ((diff.abs() <= k * se + 1e-4 * mean)).all(), (a, b, mean, diff, se)
    return mean, diff


def test_utah_whitted_distributed_agree_at_two_terms():
    scene = ir.load_scene("cornell_box", resolution=(24, 24), ambient=(0.1, 0.05, 0.02))
    for name in ("whitted", "distributed"):
        mean, diff = assert_agree(scene, name, "utah", range(6), spp=32, max_depth=2)
        assert (diff.abs() < 0.01 * mean).all()


def black_diffuse(scene, glossy_ks=None):
    """``scene`` with every diffuse reflectance set to 0 (and the glossy block's k_s if given)."""
    with torch.no_grad():
        for name in ("white", "red", "green"):
            scene.params[f"{name}.reflectance"].zero_()
        if glossy_ks is not None:
            scene.params["glossy.specular_reflectance"].fill_(glossy_ks)
    return scene


def test_whitted_equals_path_through_mirrors_and_glass():
    scene = black_diffuse(ir.load_scene("cornell_specular", resolution=(32, 32), subdivisions=3), glossy_ks=0.0)
    _, diff = assert_agree(scene, "whitted", "path", range(8), spp=32, max_depth=8)
    assert (diff.abs() > 0).all()  # the two estimators really differ beyond the directly seen light


def test_distributed_equals_path_on_glossy_and_specular_chains():
    scene = black_diffuse(ir.load_scene("cornell_specular", resolution=(32, 32), subdivisions=3))
    assert_agree(scene, "distributed", "path", range(8), spp=32, max_depth=6)
    # and per pixel, in the glossy block's and the mirror's pixels alike
    a = ir.render(scene, "distributed", spp=256, max_depth=6, seed=1, progress=False)
    b = ir.render(scene, "path", spp=256, max_depth=6, seed=2, progress=False)
    assert float((a - b).abs().mean()) < 0.05 * float(b.mean()) + 1e-4
