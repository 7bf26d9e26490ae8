"""Path records traced by the fused bounce (each contribution's monomial code computed in its
kernels) against the same records decoded from forward-mode tangents by the torch bounce."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

import invrender as ir
from invrender.backends import kernels
from invrender.core import fused as fused_bounce

pytestmark = pytest.mark.warp
FORWARD = Path(__file__).resolve().parents[2] / "forward"
NAMES = ["white.reflectance", "red.reflectance", "green.reflectance", "light.emission"]


@pytest.mark.parametrize(
    "scene_name, names, strategy",
    [("cornell_box", NAMES, "mis"), ("cornell_box", NAMES[1:3], "mis"), ("cornell_box", NAMES, "emitter"), ("cornell_box", ["light.emission"], "bsdf"),
     ("cornell_specular", NAMES, "mis"), (str(FORWARD / "textured_floor.toml"), NAMES, "mis")],  # beside a mirror, a glass, a glossy lobe; beside a texture
)  # fmt: skip
def test_fused_records_equal_the_tangent_decoded_ones(scene_name, names, strategy, monkeypatch):
    scene = ir.load_scene(scene_name, resolution=(16, 16))
    coded = []  # the bounces whose codes the kernels gave
    tangents_add = fused_bounce.tangents_add
    monkeypatch.setattr(fused_bounce, "tangents_add", lambda *a, **k: (coded.append(k.get("places") is not None), tangents_add(*a, **k))[1])
    fused = ir.record_paths(scene, names, spp=16, max_depth=6, seed=3, progress=False, strategy=strategy)
    assert coded and all(coded)
    monkeypatch.setenv(kernels.ENV, "steps")  # the torch bounce, forward-mode tangents
    torch_bounce = ir.record_paths(scene, names, spp=16, max_depth=6, seed=3, progress=False, strategy=strategy)
    assert len(coded) == sum(coded)  # none more
    assert torch.equal(fused.exponents, torch_bounce.exponents) and fused.exponents.shape[0] >= len(names)
    scale = float(torch_bounce.coefficients.abs().max())
    assert (fused.coefficients - torch_bounce.coefficients).abs().max() <= 1e-5 * scale  # (the dielectric's and glossy lobe's maths round differently compiled: 1.5e-6)
    values = {n: scene.params[n] * 0.7 for n in names}
    a, b = fused.jacobian(values), torch_bounce.jacobian(values)
    for n in names:
        assert (a[n] - b[n]).abs().max() <= 1e-5 * float(b[n].abs().max())
    monkeypatch.delenv(kernels.ENV)
    image = ir.render(scene, spp=16, max_depth=6, seed=3, progress=False, strategy=strategy)
    assert (fused.image().float() - image).abs().max() <= 1e-5 * float(image.max())


def test_records_the_fused_bounce_cannot_code_take_the_tangents():
    """A textured reflectance (texel monomials): the torch bounce records it, as before."""
    scene = ir.load_scene(str(FORWARD / "textured_floor.toml"), resolution=(8, 8))
    textured = next(n for n, v in scene.params.items() if v.ndim == 3)
    rec = ir.record_paths(scene, [textured], spp=4, max_depth=3, seed=1, progress=False)
    image = ir.render(scene, spp=4, max_depth=3, seed=1, progress=False)
    assert (rec.image().float() - image).abs().max() <= 1e-4 * float(image.max())
