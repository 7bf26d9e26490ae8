"""Normal and bump maps in TOML scenes (``normalmap = ...`` / ``bumpmap = { ... }`` in a material
table): read as Mitsuba's wrappers are, so a TOML scene renders as the same Mitsuba XML scene with
``twosided`` around the map; their one-line errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

import invrender as ir
from invrender.errors import SceneError
from invrender.scene.formats.toml import load_toml

TOML = """
resolution = [16, 16]
[camera]
origin = [0, 0, 4]
target = [0, 0, 0]
fov = 40
[materials.plane]
type = "{type}"
{perturbation}
[materials.black]
reflectance = 0
[emitters.light]
emission = 4
[[shapes]]
type = "rectangle"
material = "plane"
transform = [{{ rotate = {{ axis = [0, 0, 1], angle = 30 }} }}]
[[shapes]]
type = "rectangle"
material = "black"
emitter = "light"
transform = [{{ rotate = {{ axis = [0, 1, 0], angle = -90 }} }}, {{ translate = [1.5, 0, 1] }}]
"""

XML = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/><transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/><rfilter type="box"/></film></sensor>
  <shape type="rectangle"><transform name="to_world"><rotate z="1" angle="30"/></transform>
    <bsdf type="twosided"><bsdf type="{wrapper}">{texture}<bsdf type="{type}"/></bsdf></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="-90"/><translate x="1.5" y="0" z="1"/></transform>
    <bsdf type="twosided"><bsdf type="diffuse"><float name="reflectance" value="0"/></bsdf></bsdf>
    <emitter type="area"><rgb name="radiance" value="4"/></emitter></shape>
</scene>"""


def textures(folder) -> None:
    """normals.png: normals tilted towards +u by 0.4 rad, plus a wave along u, and towards +v (the
    green channel); height.png: a ramp in u. Both vary along u only: the XML reader's rectangle has
    its texture's rows the other way up from the TOML one's (its v points down, as Mitsuba's)."""
    y, x = np.meshgrid((np.arange(8) + 0.5) / 8, (np.arange(8) + 0.5) / 8, indexing="ij")
    n = np.stack([np.sin(0.4) + 0.3 * np.sin(2 * np.pi * x), np.full_like(x, 0.3), np.full_like(x, np.cos(0.4))], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    Image.fromarray(np.round((n + 1) / 2 * 255).astype(np.uint8)).save(folder / "normals.png")
    Image.fromarray(np.round(np.repeat(x[..., None], 3, -1) * 255).astype(np.uint8)).save(folder / "height.png")


@pytest.mark.parametrize(
    "perturbation, wrapper, texture",
    [
        ('normalmap = "normals.png"', "normalmap", '<texture name="normalmap" type="bitmap"><string name="filename" value="normals.png"/><boolean name="raw" value="true"/></texture>'),
        ('bumpmap = { file = "height.png", scale = 0.3 }', "bumpmap", '<texture type="bitmap"><string name="filename" value="height.png"/><boolean name="raw" value="true"/></texture><float name="scale" value="0.3"/>'),
    ],
)
def test_toml_maps_render_as_mitsuba_xml_wrappers(tmp_path, perturbation, wrapper, texture):
    textures(tmp_path)
    toml = tmp_path / "s.toml"
    toml.write_text(TOML.format(type="diffuse", perturbation=perturbation))
    (tmp_path / "s.xml").write_text(XML.format(wrapper=wrapper, texture=texture, type="diffuse"))
    scene, reference = load_toml(toml), ir.load_scene(str(tmp_path / "s.xml"))
    p, q = scene.material_specs[0].perturbation, reference.material_specs[0].perturbation
    assert (p.kind, p.scale, p.on_turned, p.flip_invalid, p.shadowing) == (q.kind, q.scale, q.on_turned, q.flip_invalid, q.shadowing) == (wrapper, p.scale, True, True, True)
    assert torch.equal(p.texture, q.texture)
    image, expected = ir.render(scene, spp=8, seed=1), ir.render(reference, spp=8, seed=1)
    assert float(image.mean()) > 0.01
    assert torch.allclose(image, expected, rtol=1e-4, atol=1e-5)
    flat = tmp_path / "flat.toml"
    flat.write_text(TOML.format(type="diffuse", perturbation=""))
    assert (ir.render(load_toml(flat), spp=8, seed=1) - image).abs().mean() > 0.05 * float(image.mean())  # the map changes the image


def test_toml_map_options_and_a_transmitting_material(tmp_path):
    textures(tmp_path)
    path = tmp_path / "s.toml"
    path.write_text(TOML.format(type="dielectric", perturbation='normalmap = { file = "normals.png", flip_invalid_normals = false, use_shadowing_function = false }'))
    p = load_toml(path).material_specs[0].perturbation
    assert (p.kind, p.on_turned, p.flip_invalid, p.shadowing) == ("normalmap", False, False, False)  # glass: the front side's frame
    codes = torch.from_numpy(np.asarray(Image.open(tmp_path / "normals.png"), dtype=np.float32) / 255)
    assert torch.equal(p.texture, codes)  # as stored: not sRGB-decoded


@pytest.mark.parametrize(
    "perturbation, words",
    [
        ('normalmap = "missing.png"', "[materials.plane] normalmap: image file not found"),
        ('normalmap = "grey.png"', "normalmap: grey.png: the normal at texel (row 0, column 0) is of length"),
        ('normalmap = 3', "'normalmap' must be an image file name or a table"),
        ('normalmap = { file = "normals.png", scale = 2 }', "unknown key 'scale'"),
        ('bumpmap = { file = "height.png", size = 2 }', "unknown key 'size'"),
        ('bumpmap = { scale = 2 }', "missing required key 'file'"),
        ('bumpmap = { file = "height.png", scale = "big" }', "'scale' must be a number"),
        ('normalmap = "normals.png"\nbumpmap = "height.png"', "give either 'normalmap' or 'bumpmap', not both"),
        ('normalmap = { file = "normals.png", flip_invalid_normals = 1 }', "'flip_invalid_normals' must be true or false"),
        ('normal_map = "normals.png"', "unknown key 'normal_map'"),
    ],
)
def test_toml_map_errors_are_one_line(tmp_path, perturbation, words):
    textures(tmp_path)
    Image.fromarray(np.full((2, 2, 3), 128, dtype=np.uint8)).save(tmp_path / "grey.png")
    path = tmp_path / "s.toml"
    path.write_text(TOML.format(type="diffuse", perturbation=perturbation))
    with pytest.raises(SceneError) as e:
        load_toml(path)
    assert words in str(e.value) and "\n" not in str(e.value), str(e.value)
