"""Texture lookups: bilinear with repeat wrapping, texel centres, differentiable in the texels."""

import torch

from invrender.core.textures import gather_rgb, lookup


def test_texel_centres_and_bilinear_midpoint():
    tex = torch.arange(2 * 4 * 3, dtype=torch.float32).reshape(2, 4, 3)  # h=2, w=4
    centres = torch.tensor([[(j + 0.5) / 4, 1 - (i + 0.5) / 2] for i in range(2) for j in range(4)])
    assert torch.allclose(lookup(tex, centres), tex.reshape(8, 3))
    mid = lookup(tex, torch.tensor([[1.0 / 4, 0.75]]))  # halfway between texels (0, 0) and (0, 1): top row
    assert torch.allclose(mid, (tex[0, 0] + tex[0, 1]) / 2)
    wrap = lookup(tex, torch.tensor([[0.0, 0.75]]))  # halfway between the last and first column
    assert torch.allclose(wrap, (tex[0, 3] + tex[0, 0]) / 2)


def test_gather_mixes_constants_textures_and_none():
    const = torch.tensor([0.1, 0.2, 0.3], requires_grad=True)
    tex = torch.full((3, 3, 3), 0.5, requires_grad=True)
    index = torch.tensor([0, 1, -1, 1])
    uv = torch.rand(4, 2)
    out = gather_rgb([const, tex], index, uv)
    assert torch.allclose(out, torch.tensor([[0.1, 0.2, 0.3], [0.5] * 3, [0.0] * 3, [0.5] * 3]))
    out.sum().backward()
    assert torch.allclose(const.grad, torch.ones(3))
    assert torch.isclose(tex.grad.sum(), torch.tensor(6.0))  # two lookups x 3 channels, weights sum to 1
