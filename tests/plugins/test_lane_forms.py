"""Every registered material is written once, as lane functions (``LaneForm``), and its compiled
evaluation (Dr.Jit) agrees with its eager torch one lane by lane: the same directions, weights,
pdfs and delta flags from the same uniforms, inside and outside, at grazing and random angles. The
eager evaluation is the material's differentiable ``eval`` / ``pdf`` / ``sample``, which the
conformance checks and the materials' own tests hold to closed forms and Mitsuba's values."""

from __future__ import annotations

import pytest
import torch

import invrender  # noqa: F401  (registers the built-in materials)
from invrender.backends import arrays
from invrender.core import compiled, lanes
from invrender.core.bsdf import LaneBSDF, Lobe
from invrender.plugins.bsdfs import checks
from invrender.registry import MATERIALS

TYPES = MATERIALS.names()
#: materials still written in torch alone (the torch bounce renders them); shrinks to nothing
NOT_YET: set[str] = set()
XP = arrays.drjit_arrays(torch.device("cpu"))
#: materials of nested ones, by their argument names (the registry builds each combination's type):
#: delta lobes inside a blend and a mask, a rough transmitter, composites nested in composites
VARIANTS = ["blendbsdf(roughplastic,dielectric)", "blendbsdf(glossy,roughdielectric_ggx)", "blendbsdf(pplastic,plastic)", "mask(blendbsdf(diffuse,mirror))", "mask(roughdielectric)", "mask(principled)"]


def test_every_material_is_written_once():
    for name in TYPES:
        if name not in NOT_YET:
            assert issubclass(MATERIALS[name], LaneBSDF), f"{name} has no lane form"


def test_every_emitter_is_written_once():
    """Every registered emitter type gives its lane form (``Light.lanes``): its scenes render on the
    compiled bounce (tests/transport/test_fused.py renders each beside an area light, and
    tests/transport/test_light_lanes.py holds each type's lane functions to its torch methods)."""
    from invrender.core.lights import Light
    from invrender.registry import EMITTERS

    for name in EMITTERS.names():
        assert EMITTERS[name].lanes is not Light.lanes, f"{name} has no lane form"


def lanes_at(n: int, seed: int):
    """Local directions wo, wi (3-tuples of (n,)), front (n,) bool and uniforms (3, n): random over
    the sphere, a quarter of them grazing (|z| < 0.05), wo below the normal for a tenth."""
    g = torch.Generator().manual_seed(seed)

    def directions():
        z = torch.rand(n, generator=g) * 2 - 1
        z[: n // 4] = (torch.rand(n // 4, generator=g) - 0.5) * 0.1
        phi = torch.rand(n, generator=g) * 6.2831853
        return checks.local_directions(z, phi)

    wo, wi = directions(), directions()
    wo[n // 10 :, 2] = wo[n // 10 :, 2].abs()
    front = torch.rand(n, generator=g) < 0.7
    return wo, wi, front, torch.rand(3, n, generator=g)


def _eval(xp, table, m, wo, wi, front, u_lobe, u0, u1, *, form, layout):
    p = lanes.material_values(xp, table, m, layout)
    f, pdf = form.eval(xp, p, p, wo, wi, front)
    zero = 0.0 * u0
    world = {"frame": ((zero + 1.0, zero, zero), (zero, zero + 1.0, zero), (zero, zero, zero + 1.0))} if form.world else {}  # world = local
    ws, weight, pdf_s, delta = form.sample(xp, p, p, wo, front, u_lobe, u0, u1, **world)
    return f, pdf, ws, weight, pdf_s, delta


#: the types with an anisotropic form (the constant ``alpha_v``), checked in that form too
ANISOTROPIC = [n for n in TYPES if "alpha_v" in MATERIALS[n].constants]


@pytest.mark.skipif(XP is None, reason="Dr.Jit's LLVM backend is not available")
@pytest.mark.parametrize("name", [n for n in TYPES if n not in NOT_YET] + [f"{n}:anisotropic" for n in ANISOTROPIC] + VARIANTS)
def test_compiled_lane_form_equals_eager(name):
    name, _, variant = name.partition(":")
    cls = MATERIALS[name]
    extra = {k: 0.5 for k in cls.params if k.rpartition(".")[2] == "spec_trans"}
    if variant:
        extra = {"alpha_v": 0.4}
    bsdf = checks.instance(cls, **extra)
    form = bsdf.lane_form()
    table, layout = lanes.material_rows(bsdf, form.keys, lanes.TextureTable())
    n = 4096
    wo, wi, front, u = lanes_at(n, seed=len(name))
    m = torch.zeros(n, dtype=torch.int32)
    args = (table, m, wo, wi, front, u[0], u[1], u[2])
    eager = compiled.evaluate(arrays.TORCH, _eval, *args, form=form, layout=layout)
    jit = compiled.evaluate(XP, _eval, *args, form=form, layout=layout)
    for label, a, b in zip(("f", "pdf", "wi", "weight", "sample pdf", "delta"), eager, jit):
        if a.dtype == torch.bool:
            assert (a != b).float().mean() < 1e-3, (name, label)
            continue
        scale = a.abs().amax().clamp_min(1.0)
        close = (a - b).abs() <= 1e-4 * scale + 1e-4 * a.abs()
        assert close.float().mean() > 0.999, (name, label, float((a - b).abs().max()))
    assert bool(torch.isfinite(jit[3]).all() and torch.isfinite(jit[1]).all()), name
    if cls.has(Lobe.SMOOTH):
        assert float(eager[4].amax()) > 0, name
