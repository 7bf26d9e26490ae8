"""Every registered material passes the BSDF conformance checks (invrender.plugins.bsdfs.checks), so a
new material gets them without writing a test: its sampling against its pdf (chi-square), its sample
weights against eval / pdf, its delta samples against its listed delta lobes, and its albedo below 1.
Every registered emitter type infinitely far away passes invrender.plugins.emitters.checks: its pdf
integrates to 1 and its samples follow it (chi-square)."""

from __future__ import annotations

import pytest
import torch

import invrender  # noqa: F401  (registers the built-in materials)
from invrender.plugins.bsdfs import checks
from invrender.registry import MATERIALS
from invrender.core.bsdfs import Lobe

TYPES = MATERIALS.names()
ANGLES = [0.0, 0.8, 1.35]


def test_the_registry_holds_the_built_in_materials():
    assert TYPES[:4] == ["diffuse", "mirror", "dielectric", "glossy"]
    for name in TYPES:
        cls = MATERIALS[name]
        assert cls.type_name == name and cls.lobes and cls.doc, name


@pytest.mark.parametrize("theta_o", ANGLES)
@pytest.mark.parametrize("name", TYPES)
def test_sampling_matches_pdf(name, theta_o):
    cls = MATERIALS[name]
    if not cls.has(Lobe.SMOOTH):
        pytest.skip(f"{name} has delta lobes only: no density to test")
    assert checks.chi_square_p(checks.instance(cls), theta_o, seed=int(theta_o * 10)) > 1e-3


@pytest.mark.parametrize("theta_o", ANGLES)
@pytest.mark.parametrize("name", [n for n in TYPES if MATERIALS[n].has(Lobe.GLOSSY_TRANSMISSION)])
def test_sampling_from_inside_matches_pdf(name, theta_o):
    """Materials that transmit through a smooth lobe, seen from inside (wo behind the surface:
    the index ratio inverted, total internal reflection): sampling against pdf, weights against
    eval / pdf. A material whose transmission is a parameter (the principled materials'
    ``spec_trans``, default 0) is checked with it at 1."""
    cls = MATERIALS[name]
    bsdf = checks.instance(cls, **({"spec_trans": 1.0} if "spec_trans" in cls.params else {}))
    assert checks.chi_square_p(bsdf, theta_o, seed=int(theta_o * 10), front=False) > 1e-3
    pdf_err, weight_err, smooth = checks.weight_errors(bsdf, theta_o, front=False)
    assert pdf_err < 2e-3 and weight_err < 2e-3 and smooth > 0.3


@pytest.mark.parametrize("theta_o", [0.2, 1.0])
@pytest.mark.parametrize("name", TYPES)
def test_sample_weight_is_eval_over_pdf(name, theta_o):
    cls = MATERIALS[name]
    pdf_err, weight_err, smooth = checks.weight_errors(checks.instance(cls), theta_o)
    assert pdf_err < 2e-3 and weight_err < 2e-3
    assert (smooth > 0.3) == cls.has(Lobe.SMOOTH)  # smooth lobes are sampled, delta-only ones never


@pytest.mark.parametrize("theta_o", [0.3, 1.2])
@pytest.mark.parametrize("name", TYPES)
def test_delta_samples_carry_the_delta_lobes_weights(name, theta_o):
    cls = MATERIALS[name]
    bsdf = checks.instance(cls)
    sp = checks.shading_point(theta_o, 8)
    lobes = bsdf.specular_lobes(sp)
    assert bool(lobes) == cls.has(Lobe.DELTA)
    if lobes:
        assert checks.delta_weight_gap(bsdf, theta_o) < 5e-3
        assert float(bsdf.eval(sp, lobes[0][0]).abs().max()) == 0 or cls.has(Lobe.SMOOTH)


@pytest.mark.parametrize("name", TYPES)
def test_albedo_at_most_one(name):
    """The mean sample weight (the directional albedo) of a material at its defaults is <= 1."""
    bsdf = checks.instance(MATERIALS[name])
    n = 100_000
    g = torch.Generator().manual_seed(11)
    for theta_o in ANGLES:
        bs = bsdf.sample(checks.shading_point(theta_o, n), torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
        assert float(bs.weight.double().mean(0).max()) <= 1.0 + 5e-3


# ---------------------------------------------------------------- emitters infinitely far away


def _environment(name: str):
    """An instance of the registered emitter type ``name`` with its default values, in a scene of
    one cube."""
    from invrender.registry import EMITTERS
    from invrender.scene.camera import Camera
    from invrender.scene.emitters import Emitter
    from invrender.scene.scene import build_scene
    from invrender.scene.shapes import Mesh, cube

    scene = build_scene([Mesh(*cube(), material="m")], {"m": 0.5}, {"e": Emitter.of(name)}, Camera(origin=(3, 2, 3), target=(0, 0, 0)), (4, 4))
    return EMITTERS[name]([0], [{"emission": scene.params["e.emission"]}], [dict(scene.emitter_spec(0).constants)], scene.triangles)


def _infinite_types():
    from invrender.registry import EMITTERS

    return [name for name in EMITTERS.names() if EMITTERS[name].infinite]


@pytest.mark.parametrize("name", _infinite_types())
def test_an_environments_sampling_matches_its_pdf(name):
    from invrender.plugins.emitters import checks as emitter_checks

    light = _environment(name)
    assert emitter_checks.pdf_integral(light) == pytest.approx(1.0, abs=2e-3)
    assert emitter_checks.chi_square_p(light, samples=100_000) > 1e-3
