"""Normal and bump maps (Mitsuba's ``normalmap`` and ``bumpmap`` wrappers, :mod:`invrender.core.shading`):
the nested material's value and pdf at hits of a tilted, rotated rectangle against Mitsuba 3.9.1's on
the same rays, from the front and from behind, with ``twosided`` outside the map and inside it; the
XML reader's handling of the wrappers and its one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

import invrender as ir
from invrender.core.context import TransportContext
from invrender.core.surface import surface_at
from invrender.errors import SceneError

#: hits from 2 units along ``-d`` (5 from the front, 3 from behind) and light directions on the
#: camera's side; Mitsuba's ``si.bsdf().eval`` and ``pdf`` (llvm_ad_rgb) at them, for each case of
#: :data:`CASES` (``scene.ray_intersect`` of the same file and the same textures)
RAYS = json.loads('''{"origin": [[0.468504, -1.170322, 1.476052], [0.139353, 0.406273, 2.119803], [0.851877, -1.761395, -0.638354], [-0.259701, -2.425293, 0.078145], [1.071523, -1.841446, 1.169794], [0.347807, -1.678233, -1.083781], [-0.123315, 0.52936, -1.920231], [0.897498, -0.011288, -1.215035]], "d": [[-0.438771, 0.217183, -0.871959], [0.128171, -0.015562, -0.99163], [-0.712191, 0.660091, 0.238883], [0.26664, 0.954575, -0.133003], [-0.179079, 0.736963, -0.65178], [-0.266216, 0.805382, 0.529612], [-0.031472, -0.230442, 0.972577], [-0.468693, 0.440395, 0.765754]], "light": [[-0.316066, -0.800948, 0.508512], [0.998508, -0.024234, 0.04893], [-0.876466, -0.466049, -0.120854], [-0.76074, 0.140649, 0.633634], [-0.685174, -0.68339, 0.252021], [-0.298339, 0.087334, -0.950456], [0.374076, 0.266342, -0.888329], [-0.049984, 0.785449, -0.616905]]}''')
MITSUBA = json.loads('''{"normalmap_outside": [[[0.0239756, 0.0239756, 0.0239756], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.235456, 0.235456, 0.235456], [0.0224166, 0.0224166, 0.0224166], [0.0844728, 0.0844728, 0.0844728], [0.0272911, 0.0272911, 0.0272911], [0.0109729, 0.0109729, 0.0109729]], [0.0285975, 0.0, 0.0, 0.249566, 0.0394459, 0.0848894, 0.0285421, 0.0268067]], "twosided_normalmap": [[[0.0239756, 0.0239756, 0.0239756], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.235456, 0.235456, 0.235456], [0.0224166, 0.0224166, 0.0224166], [0.0377898, 0.0377898, 0.0377898], [0.209973, 0.209973, 0.209973], [0.0109729, 0.0109729, 0.0109729]], [0.0285975, 0.0, 0.0, 0.249566, 0.0394459, 0.0398066, 0.210633, 0.0268067]], "twosided_bumpmap": [[[0.26183, 0.26183, 0.26183], [0.0123134, 0.0123134, 0.0123134], [0.0145103, 0.0145103, 0.0145103], [0.0409769, 0.0409769, 0.0409769], [0.039745, 0.039745, 0.039745], [0.0749231, 0.0749231, 0.0749231], [0.376288, 0.376288, 0.376288], [0.334501, 0.334501, 0.334501]], [0.266766, 0.0294825, 0.0423057, 0.042834, 0.0424932, 0.0752661, 0.37768, 0.336726]]}
''')

SCENE = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/><transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>
  <shape type="rectangle"><transform name="to_world"><rotate z="1" angle="30"/><rotate x="1" angle="20"/></transform>
  {bsdf}
  </shape></scene>"""
NM = '<texture name="normalmap" type="bitmap"><string name="filename" value="normals.png"/><boolean name="raw" value="true"/></texture>'
HM = '<texture type="bitmap"><string name="filename" value="height.png"/><boolean name="raw" value="true"/></texture>'
GLOSSY = '<bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/></bsdf>'
CASES = {
    "normalmap_outside": f'<bsdf type="normalmap">{NM}<bsdf type="twosided">{GLOSSY}</bsdf></bsdf>',
    "twosided_normalmap": f'<bsdf type="twosided"><bsdf type="normalmap">{NM}{GLOSSY}</bsdf></bsdf>',
    "twosided_bumpmap": f'<bsdf type="twosided"><bsdf type="bumpmap">{HM}<float name="scale" value="0.05"/>{GLOSSY}</bsdf></bsdf>',
}


def write_textures(folder, size: int = 16) -> None:
    """normals.png (8 bits, (n + 1) / 2) and height.png of a smooth height field."""
    y, x = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size, indexing="ij")
    h = 0.5 + 0.3 * np.sin(2 * np.pi * x) * np.cos(2 * np.pi * 2 * y)
    dx = np.gradient(h, axis=1) * size * 0.5
    dy = -np.gradient(h, axis=0) * size * 0.5
    n = np.stack([-dx, -dy, np.ones_like(h)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    Image.fromarray(np.round((n + 1) / 2 * 255).astype(np.uint8)).save(folder / "normals.png")
    Image.fromarray(np.round(np.repeat(h[..., None], 3, -1) * 255).astype(np.uint8)).save(folder / "height.png")


def _shade(path):
    scene = ir.load_scene(str(path), resolution=(4, 4))
    ctx = TransportContext.build(scene, torch.device("cpu"))
    o, d, light = (torch.tensor(RAYS[k], dtype=torch.float32) for k in ("origin", "d", "light"))
    hits = ctx.accel.intersect(o, d)
    assert bool(hits.valid.all())
    s = surface_at(ctx.triangles, hits, d)
    sp = ctx.shading_point(s, -d)
    return ctx.materials.eval(sp, light), ctx.materials.pdf(sp, light)


@pytest.mark.parametrize("case", sorted(CASES))
def test_value_and_pdf_are_mitsubas(case, tmp_path):
    write_textures(tmp_path)
    path = tmp_path / "plane.xml"
    path.write_text(SCENE.format(bsdf=CASES[case]))
    f, pdf = _shade(path)
    f_mi, pdf_mi = MITSUBA[case]
    assert f.reshape(-1).tolist() == pytest.approx(np.ravel(f_mi).tolist(), rel=2e-3, abs=1e-6)
    assert pdf.tolist() == pytest.approx(pdf_mi, rel=2e-3, abs=1e-6)


@pytest.mark.parametrize("case", sorted(CASES))
def test_samples_weigh_value_over_pdf(case, tmp_path):
    """A perturbed material's samples: pdf = pdf(wi), weight = eval / pdf (the masks and the
    shadowing term on both), zero where wi falls between the base and the perturbed normal."""
    write_textures(tmp_path)
    path = tmp_path / "plane.xml"
    path.write_text(SCENE.format(bsdf=CASES[case]))
    scene = ir.load_scene(str(path), resolution=(4, 4))
    ctx = TransportContext.build(scene, torch.device("cpu"))
    g = torch.Generator().manual_seed(1)
    n = 4096
    o = torch.tensor(RAYS["origin"]).repeat(n // 8, 1)
    d = torch.tensor(RAYS["d"]).repeat(n // 8, 1)
    s = surface_at(ctx.triangles, ctx.accel.intersect(o, d), d)
    sp = ctx.shading_point(s, -d)
    bs = ctx.materials.sample(sp, torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    ok = bs.pdf > 1e-2
    assert float(ok.float().mean()) > 0.5
    f, pdf = ctx.materials.eval(sp, bs.wi)[ok], ctx.materials.pdf(sp, bs.wi)[ok]
    assert torch.allclose(bs.pdf[ok], pdf, rtol=2e-3, atol=1e-5)
    assert torch.allclose(bs.weight[ok], f / pdf[:, None], rtol=2e-3, atol=1e-5)
    assert bool(torch.isfinite(bs.weight).all())


def test_the_reader_unwraps_the_maps_onto_the_nested_material(tmp_path):
    write_textures(tmp_path)
    for case, kind, turned in (("normalmap_outside", "normalmap", False), ("twosided_normalmap", "normalmap", True), ("twosided_bumpmap", "bumpmap", True)):
        path = tmp_path / f"{case}.xml"
        path.write_text(SCENE.format(bsdf=CASES[case]))
        spec = ir.load_scene(str(path), resolution=(4, 4)).material_specs[0]
        p = spec.perturbation
        assert spec.type == "glossy" and not spec.one_sided
        assert (p.kind, p.on_turned, p.flip_invalid, p.shadowing) == (kind, turned, True, True)
        assert p.texture.shape == (16, 16, 3) and p.scale == (0.05 if kind == "bumpmap" else 1.0)
        assert "normals.png" in p.source or "height.png" in p.source
    # raw=true: the codes as stored, not decoded from sRGB
    assert float(ir.load_scene(str(tmp_path / "twosided_normalmap.xml"), resolution=(4, 4)).material_specs[0].perturbation.texture[..., 2].min()) > 0.7  # sRGB-decoded: 0.55


def _map_with(tmp_path, name: str, texel) -> None:
    """A 4 x 4 flat normal map with ``texel`` at (1, 2): an 8-bit PNG, or a float EXR."""
    img = np.tile(np.array([0.5, 0.5, 1.0], dtype=np.float32), (4, 4, 1))
    img[1, 2] = texel
    if name.endswith(".png"):
        Image.fromarray((img * 255).round().astype(np.uint8)).save(tmp_path / name)
    else:
        from invrender.io import images

        with open(tmp_path / name, "wb") as f:
            images._write_exr(f, img)


@pytest.mark.parametrize(
    "bsdf, message",
    [
        (f'<bsdf type="normalmap"><texture name="normalmap" type="bitmap"><string name="filename" value="grey.png"/><boolean name="raw" value="true"/></texture>{GLOSSY}</bsdf>',
         "grey.png: the normal at texel (row 1, column 2) is of length 0.00679: a normal map's texels encode unit normals n as (n + 1) / 2"),
        (f'<bsdf type="normalmap"><texture name="normalmap" type="bitmap"><string name="filename" value="nan.exr"/></texture>{GLOSSY}</bsdf>',
         "nan.exr: the normal at texel (row 1, column 2) is not a number"),
        (f'<bsdf type="normalmap">{GLOSSY}</bsdf>', 'normalmap needs a <texture name="normalmap" type="bitmap">'),
        (f'<bsdf type="bumpmap">{GLOSSY}</bsdf>', "bumpmap needs exactly one nested <texture> (the height)"),
        (f'<bsdf type="bumpmap">{HM}<bsdf type="normalmap">{NM}{GLOSSY}</bsdf></bsdf>', "a normalmap inside a bumpmap is not supported (one normal perturbation per material)"),
        (f'<bsdf type="twosided"><bsdf type="normalmap">{NM}<bsdf type="roughdielectric"/></bsdf></bsdf>', "twosided cannot wrap a normalmap of a BSDF that transmits"),
        (f'<bsdf type="normalmap">{NM}{GLOSSY}{GLOSSY}</bsdf>', "normalmap must wrap exactly one BSDF"),
        (f'<bsdf type="normalmap">{NM}<float name="strength" value="2"/>{GLOSSY}</bsdf>', "unsupported property 'strength'"),
    ],
)
def test_bad_maps_are_one_line_errors(bsdf, message, tmp_path):
    write_textures(tmp_path)
    _map_with(tmp_path, "grey.png", [128 / 255, 128 / 255, 128 / 255])
    _map_with(tmp_path, "nan.exr", [float("nan"), 0.5, 1.0])
    path = tmp_path / "bad.xml"
    path.write_text(SCENE.format(bsdf=bsdf))
    with pytest.raises(SceneError) as e:
        ir.load_scene(str(path), resolution=(4, 4))
    assert message in str(e.value) and "\n" not in str(e.value)
