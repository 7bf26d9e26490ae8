"""A textured ``alpha`` on Mitsuba's ``roughconductor`` (a roughness map, as on ``roughdielectric``):
read as Mitsuba's ``eval_1`` reads it, clamped at 1e-4; a uniform map renders as the number; the
anisotropic ``alpha_u``/``alpha_v`` stay numbers (one-line error for a texture)."""

from __future__ import annotations

import pytest
import torch

import invrender as ir
from invrender.errors import SceneError
from invrender.io import write_image

BODY = """
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-50"/></transform>
    <bsdf type="roughconductor"><string name="distribution" value="{distribution}"/><string name="material" value="Au"/>{alpha}</bsdf></shape>
  <emitter type="constant"><rgb name="radiance" value="0.05"/></emitter>
  <shape type="sphere"><transform name="to_world"><scale value="0.3"/><translate x="0" y="1.2" z="1.2"/></transform>
    <emitter type="area"><rgb name="radiance" value="20"/></emitter></shape>"""
SENSOR = """<sensor type="perspective"><float name="fov" value="45"/><transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="12"/><integer name="height" value="12"/><rfilter type="box"/></film></sensor>"""


def scene_file(path, alpha: str, distribution: str = "ggx"):
    path.write_text(f'<scene version="3.0.0">{SENSOR}{BODY.format(alpha=alpha, distribution=distribution)}</scene>')
    return ir.load_scene(str(path))


def test_checkerboard_alpha_is_a_clamped_roughness_map(tmp_path):
    board = '<texture name="alpha" type="checkerboard"><float name="color0" value="0"/><float name="color1" value="0.4"/></texture>'
    scene = scene_file(tmp_path / "c.xml", board, "beckmann")
    (name,) = [k for k in scene.params if k.endswith(".roughness")]
    alpha = scene.params[name]
    assert scene.material_specs[scene.materials.index(name.rpartition(".")[0])].type == "glossy_beckmann"
    assert alpha.ndim == 3 and float(alpha.min()) == pytest.approx(1e-4) and float(alpha.max()) == pytest.approx(0.4)
    assert torch.unique(alpha).tolist() == pytest.approx([1e-4, 0.4])  # Mitsuba's clamp of 0: half smooth
    assert float((alpha == alpha.min()).float().mean()) == pytest.approx(0.5, abs=0.01)


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_uniform_alpha_map_renders_as_the_number(tmp_path, distribution):
    write_image(tmp_path / "alpha.exr", torch.full((4, 4, 3), 0.3))
    bitmap = '<texture name="alpha" type="bitmap"><string name="filename" value="alpha.exr"/></texture>'
    textured, number = scene_file(tmp_path / "t.xml", bitmap, distribution), scene_file(tmp_path / "n.xml", '<float name="alpha" value="0.3"/>', distribution)
    image, expected = ir.render(textured, spp=8, seed=2), ir.render(number, spp=8, seed=2)
    assert float(expected.mean()) > 0.05
    assert torch.allclose(image, expected, rtol=1e-4, atol=1e-5)
    smoother = ir.render(scene_file(tmp_path / "s.xml", '<float name="alpha" value="0.05"/>', distribution), spp=8, seed=2)
    assert (smoother - expected).abs().mean() > 0.05 * float(expected.mean())  # the roughness shows


def test_textured_anisotropic_alpha_is_refused_in_one_line(tmp_path):
    board = '<texture name="{}" type="checkerboard"><float name="color0" value="0.05"/><float name="color1" value="0.3"/></texture>'
    with pytest.raises(SceneError) as e:
        scene_file(tmp_path / "a.xml", board.format("alpha_u") + board.format("alpha_v"))
    assert "'alpha_u' must be a <float> (a texture only for the isotropic alpha)" in str(e.value) and "\n" not in str(e.value)
