"""Mitsuba's bitmap options (``to_uv``, ``filter_type``, ``wrap_mode``), per-vertex attributes
(``mesh_attribute`` from PLY files) and ``shapegroup`` / ``instance``: lookups against values
Mitsuba 3.9.1 returned for the same texture (``mi.load_dict({"type": "bitmap", ...}).eval``),
interpolation against a hand-computed vertex-colour case, instances against the same geometry
written out flat, and the one-line errors of bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.core.textures import bilinear, gather_rgb, interpolate, lookup
from invrender.errors import SceneError
from invrender.scene.formats.mitsuba import instances
from invrender.scene.textures import TextureSampling, mitsuba_to_uv

# a 2 x 3 texture whose red channel is 0.15 x (row-major texel index): a lookup names its texels
TEXELS = torch.arange(18, dtype=torch.float32).reshape(2, 3, 3) / 20
# (u, v) in Mitsuba's convention (v down), inside and outside [0, 1]^2
MITSUBA_UV = [(0.1, 0.1), (0.5, 0.2), (0.95, 0.9), (-0.2, 0.3), (1.3, -0.4), (2.6, 1.7), (-1.1, -0.6)]
# Mitsuba 3.9.1's red channel at MITSUBA_UV (bitmap with raw data, llvm_ad_rgb)
MITSUBA = {
    ("nearest", "repeat"): [0.0, 0.15, 0.75, 0.30, 0.45, 0.60, 0.30],
    ("nearest", "clamp"): [0.0, 0.15, 0.75, 0.0, 0.30, 0.75, 0.0],
    ("nearest", "mirror"): [0.0, 0.15, 0.75, 0.0, 0.30, 0.15, 0.75],
    ("bilinear", "repeat"): [0.195, 0.195, 0.51, 0.33, 0.375, 0.60, 0.375],
    ("bilinear", "clamp"): [0.0, 0.15, 0.75, 0.045, 0.30, 0.75, 0.0],
    ("bilinear", "mirror"): [0.0, 0.15, 0.75, 0.06, 0.375, 0.24, 0.615],
}
# nearest, repeat, to_uv = translate(0.25, 0.5) . scale(2, 3) (Mitsuba's XML order: scale first)
MITSUBA_TO_UV = [0.60, 0.0, 0.0, 0.30, 0.30, 0.60, 0.45]


def uv_of(mitsuba_uv) -> torch.Tensor:
    return torch.tensor([(u, 1.0 - v) for u, v in mitsuba_uv])  # invrender's v points up


@pytest.mark.parametrize("filter,wrap", list(MITSUBA))
def test_lookups_equal_mitsubas(filter, wrap):
    got = lookup(TEXELS, uv_of(MITSUBA_UV), TextureSampling(filter, wrap))[:, 0]
    assert got.tolist() == pytest.approx(MITSUBA[(filter, wrap)], abs=1e-6)


def test_hand_computed_lookups():
    # texel coordinates x = u w, y = v h (Mitsuba's v); texel (i, j) has red 0.15 (3 i + j)
    at = uv_of([(-0.2, 0.3)])  # x = -0.6, y = 0.6: nearest texel column -1, row 0
    assert lookup(TEXELS, at, TextureSampling("nearest", "repeat"))[0, 0] == pytest.approx(0.15 * 2)  # column -1 -> 2
    assert lookup(TEXELS, at, TextureSampling("nearest", "clamp"))[0, 0] == pytest.approx(0.0)  # column -1 -> 0
    assert lookup(TEXELS, at, TextureSampling("nearest", "mirror"))[0, 0] == pytest.approx(0.0)  # column -1 -> 0
    far = uv_of([(2.6, 1.7)])  # x = 7.8 -> column 7, y = 3.4 -> row 3
    # mirror has period 2n: column 7 mod 6 = 1; row 3 mod 4 = 3 -> 2 * 2 - 1 - 3 = 0
    assert lookup(TEXELS, far, TextureSampling("nearest", "mirror"))[0, 0] == pytest.approx(0.15 * 1)
    assert lookup(TEXELS, far, TextureSampling("nearest", "clamp"))[0, 0] == pytest.approx(0.15 * 5)
    # bilinear clamp at x = 0.5 w + 0.75 (between columns 1 and 2, 3/4 of the way... minus the half texel)
    mid = uv_of([(0.5, 0.25)])  # x - 0.5 = 1.0 -> column 1 exactly; y - 0.5 = 0 -> row 0
    assert lookup(TEXELS, mid, TextureSampling("bilinear", "clamp"))[0, 0] == pytest.approx(0.15)


def test_to_uv_equals_mitsubas():
    m = np.eye(4)
    m[0, 0], m[1, 1], m[0, 3], m[1, 3] = 2.0, 3.0, 0.25, 0.5
    sampling = TextureSampling("nearest", "repeat", mitsuba_to_uv(m))
    assert lookup(TEXELS, uv_of(MITSUBA_UV), sampling)[:, 0].tolist() == pytest.approx(MITSUBA_TO_UV, abs=1e-6)
    # the conversion: Mitsuba's map applied to (u, 1 - v), flipped back
    rot = np.array([[0.6, -0.8, 0.1], [0.8, 0.6, -0.3], [0.0, 0.0, 1.0]])
    a, b, c, d, e, f = mitsuba_to_uv(rot)
    u, v = 0.3, 0.7
    s, t = rot[:2] @ np.array([u, 1 - v, 1.0])
    assert (a * u + b * v + c, d * u + e * v + f) == pytest.approx((s, 1 - t), abs=1e-12)
    assert mitsuba_to_uv(np.eye(4)) is None


def test_fixed_shapes_and_gradients():
    uv = uv_of(MITSUBA_UV)
    for filter in ("nearest", "bilinear"):
        index, weight = bilinear(2, 3, uv, TextureSampling(filter, "mirror"))
        assert index.shape == weight.shape == (len(MITSUBA_UV), 4)
        assert torch.allclose(weight.sum(1), torch.ones(len(MITSUBA_UV)))
        assert int(index.min()) >= 0 and int(index.max()) < 6
    texels = TEXELS.clone().requires_grad_(True)
    lookup(texels, uv_of([(0.5, 0.2)]), TextureSampling("nearest", "clamp"))[0, 1].backward()
    expected = torch.zeros(2, 3, 3)
    expected[0, 1, 1] = 1.0  # one texel, weight 1, green channel
    assert torch.equal(texels.grad, expected)


def test_per_vertex_interpolation_by_hand():
    value = torch.tensor([[0.1, 0.2, 0.3], [0.9, 0.1, 0.1], [0.2, 0.8, 0.2], [0.5, 0.5, 0.9]], requires_grad=True)
    corners = torch.tensor([[0, 1, 2], [0, 2, 3]])
    bary = torch.tensor([[0.4, 0.35, 0.25], [0.2, 0.3, 0.5]])
    got = interpolate(value, corners, bary)
    expected0 = [0.4 * 0.1 + 0.35 * 0.9 + 0.25 * 0.2, 0.4 * 0.2 + 0.35 * 0.1 + 0.25 * 0.8, 0.4 * 0.3 + 0.35 * 0.1 + 0.25 * 0.2]
    assert got[0].tolist() == pytest.approx(expected0, abs=1e-6)
    assert got[1].tolist() == pytest.approx((0.2 * value[0] + 0.3 * value[2] + 0.5 * value[3]).tolist(), abs=1e-6)
    got[0, 0].backward()
    assert value.grad[:, 0].tolist() == pytest.approx([0.4, 0.35, 0.25, 0.0])
    # through gather_rgb: material 0 per vertex, material 1 constant, -1 none
    out = gather_rgb([value.detach(), torch.tensor([0.7, 0.7, 0.7])], torch.tensor([0, 1, -1]), torch.zeros(3, 2), None, corners[[0, 1, 1]], bary[[0, 1, 1]])
    assert out[0].tolist() == pytest.approx(expected0, abs=1e-6) and out[1].tolist() == pytest.approx([0.7] * 3) and out[2].tolist() == [0, 0, 0]


SENSOR = """<sensor type="{camera}">{fov}<transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
<film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{w}"/><rfilter type="box"/></film></sensor>"""


def write(tmp_path, body, name="s.xml", camera="perspective", w=16):
    fov = '<float name="fov" value="40"/>' if camera == "perspective" else ""
    path = tmp_path / name
    path.write_text(f'<scene version="3.0.0">\n{SENSOR.format(camera=camera, fov=fov, w=w)}\n{body}\n</scene>\n')
    return path


def write_ply(path, colours, extra=True):
    v = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    lines = ["ply", "format ascii 1.0", "element vertex 4"] + [f"property float {a}" for a in ("x", "y", "z", "r", "g", "b")]
    lines += ["property float weight_x"] if extra else []
    lines += ["element face 2", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(str(x) for x in (*p, *c, *([0.1 * (i + 1)] if extra else []))) for i, (p, c) in enumerate(zip(v, colours))]
    path.write_text("\n".join(lines + ["3 0 1 2", "3 0 2 3", ""]))


COLOURS = [(0.1, 0.2, 0.3), (0.9, 0.1, 0.1), (0.2, 0.8, 0.2), (0.5, 0.5, 0.9)]


def test_mesh_attribute_from_ply_renders_interpolated_colours(tmp_path):
    write_ply(tmp_path / "q.ply", COLOURS)
    body = """<shape type="ply"><string name="filename" value="q.ply"/><bsdf type="diffuse">
    <texture type="mesh_attribute" name="reflectance"><string name="name" value="vertex_color"/></texture></bsdf></shape>
    <emitter type="constant"/><integrator type="path"><integer name="max_depth" value="2"/></integrator>"""
    # an orthographic camera sees [-1, 1]^2 exactly; a Lambertian plane under a uniform sky of
    # radiance 1 (all of it visible) sends rho, with no variance when only the BSDF is sampled
    # (cosine weights): each pixel is the interpolated colour averaged over its points
    scene = ir.load_scene(write(tmp_path, body, camera="orthographic", w=8))
    rho = scene.params["material_1.reflectance"]
    assert rho.shape == (4, 3) and torch.allclose(rho, torch.tensor(COLOURS))
    image = ir.render(scene, spp=64, seed=1, integrator={"type": "path", "strategy": "bsdf"}, max_depth=2)
    c = (torch.arange(8) + 0.5) / 4 - 1  # pixel centres
    x, y = c[None, :].expand(8, 8), -c[:, None].expand(8, 8)  # row 0 at the top (y = +1)
    lower = y <= x  # triangle (0, 1, 2) below the diagonal, (0, 2, 3) above
    v = torch.tensor(COLOURS)
    b2 = torch.where(lower, (y + 1) / 2, (x + 1) / 2)  # weight of the diagonal's far end (vertex 2)
    b_side = torch.where(lower, (x - y) / 2, (y - x) / 2)  # of vertex 1 (below) or 3 (above)
    expected = (1 - b2 - b_side)[..., None] * v[0] + b2[..., None] * v[2] + b_side[..., None] * torch.where(lower[..., None], v[1], v[3])
    away = (x - y).abs() > 0.3  # pixels the diagonal does not cross (there the colour is linear)
    # a linear colour averaged over 64 random points of a pixel: its centre's within 0.01
    assert float((image - expected).abs()[away].max()) < 0.01
    # a vertex attribute given as weight_x (one channel: grey)
    grey = ir.load_scene(write(tmp_path, body.replace("vertex_color", "vertex_weight"), name="g.xml", camera="orthographic", w=8))
    assert grey.params["material_1.reflectance"][:, 1].tolist() == pytest.approx([0.1, 0.2, 0.3, 0.4])


FACE_COLOURS = [(0.9, 0.2, 0.1), (0.1, 0.3, 0.8)]


def test_face_attributes_from_ply_are_constant_over_each_face(tmp_path):
    """Mitsuba's ``face_color`` (a PLY face's ``r g b``) and ``face_<x>`` (``<x>_0``): each face
    reads its own value, not interpolated; the mesh's vertex attributes still interpolate."""
    v = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    lines = ["ply", "format ascii 1.0", "element vertex 4"] + [f"property float {a}" for a in ("x", "y", "z", "r", "g", "b")]
    lines += ["element face 2", "property list uchar int vertex_indices", "property float r", "property float g", "property float b", "property float weight_0", "end_header"]
    lines += [" ".join(str(x) for x in (*p, *c)) for p, c in zip(v, COLOURS)]
    lines += ["3 0 1 2 " + " ".join(map(str, FACE_COLOURS[0])) + " 0.25", "3 0 2 3 " + " ".join(map(str, FACE_COLOURS[1])) + " 0.75", ""]
    (tmp_path / "f.ply").write_text("\n".join(lines))
    body = """<shape type="ply"><string name="filename" value="f.ply"/><bsdf type="diffuse">
    <texture type="mesh_attribute" name="reflectance"><string name="name" value="{}"/></texture></bsdf></shape>
    <emitter type="constant"/><integrator type="path"><integer name="max_depth" value="2"/></integrator>"""
    scene = ir.load_scene(write(tmp_path, body.format("face_color"), camera="orthographic", w=8))
    rho = scene.params["material_1.reflectance"]  # three vertices of its own per face, carrying the face's colour
    assert rho.shape == (6, 3) and torch.allclose(rho, torch.tensor(FACE_COLOURS).repeat_interleave(3, 0))
    image = ir.render(scene, spp=16, seed=1, integrator={"type": "path", "strategy": "bsdf"}, max_depth=2)
    c = (torch.arange(8) + 0.5) / 4 - 1
    x, y = c[None, :].expand(8, 8), -c[:, None].expand(8, 8)
    lower = y < x  # face 0 below the diagonal, face 1 above
    away = (x - y).abs() > 0.3
    expected = torch.where(lower[..., None], torch.tensor(FACE_COLOURS[0]), torch.tensor(FACE_COLOURS[1]))
    assert float((image - expected).abs()[away].max()) < 1e-4  # a constant per face: no variance
    weight = ir.load_scene(write(tmp_path, body.format("face_weight"), name="w.xml", camera="orthographic", w=8))
    assert weight.params["material_1.reflectance"][:, 0].tolist() == pytest.approx([0.25] * 3 + [0.75] * 3)
    # the vertex colours of the unwelded mesh: each corner its vertex's
    vertex = ir.load_scene(write(tmp_path, body.format("vertex_color"), name="v.xml", camera="orthographic", w=8))
    assert torch.allclose(vertex.params["material_1.reflectance"], torch.tensor(COLOURS)[[0, 1, 2, 0, 2, 3]])


def test_bitmap_options_load_and_render(tmp_path):
    ir.write_image(tmp_path / "t.exr", TEXELS)
    body = """<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="t.exr"/>
    <string name="filter_type" value="nearest"/><string name="wrap_mode" value="Mirror"/><transform name="to_uv"><scale x="2" y="3"/></transform></texture></bsdf></shape>
    <emitter type="constant"/><integrator type="path"><integer name="max_depth" value="2"/></integrator>"""
    scene = ir.load_scene(write(tmp_path, body, camera="orthographic", w=12))
    sampling = scene.texture_sampling["material_1.reflectance"]
    assert (sampling.filter, sampling.wrap) == ("nearest", "mirror")
    assert sampling.to_uv == pytest.approx((2.0, 0.0, 0.0, 0.0, 3.0, -2.0))
    image = ir.render(scene, spp=16, seed=2, integrator={"type": "path", "strategy": "bsdf"}, max_depth=2)
    # pixel centres' Mitsuba uv: u = (j + 0.5) / 12 = (x + 1) / 2, v = (y + 1) / 2 = 1 - (i + 0.5) / 12
    c = (torch.arange(12) + 0.5) / 12
    uv = torch.stack([c[None, :].expand(12, 12), 1 - c[:, None].expand(12, 12)], -1).reshape(-1, 2)
    expected = lookup(TEXELS, torch.stack([uv[:, 0], 1 - uv[:, 1]], 1), sampling).reshape(12, 12, 3)
    # nearest: a pixel straddling a texel edge would mix two texels; here each pixel (half a
    # texel wide: 12 pixels over 2 x 3 texels in u, 3 x 2 in v) lies inside one texel
    x, y = uv[:, 0] * 2 * 3, uv[:, 1] * 3 * 2  # texel coordinates of the centres
    assert bool(((x - x.round()).abs() > 0.249).all() and ((y - y.round()).abs() > 0.249).all())
    assert float((image - expected).abs().max()) < 1e-4  # no variance: rho x a sky of 1, BSDF samples only


def flat_and_instanced(tmp_path):
    group = """<shape type="cube"><transform name="to_world"><scale value="0.5"/></transform><ref id="red"/></shape>
      <shape type="rectangle"><transform name="to_world"><translate y="-1"/></transform></shape>"""
    places = ['<translate x="-1.5"/>', '<rotate y="1" angle="30"/><translate x="1.5"/>']
    common = '<bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.8, 0.2, 0.2"/></bsdf>\n<emitter type="constant"/>'
    instanced = common + f'\n<shape type="shapegroup" id="g">{group}</shape>\n' + "\n".join(
        f'<shape type="instance"><ref id="g"/><transform name="to_world">{p}</transform></shape>' for p in places)
    flat = common + "\n" + "\n".join(
        group.replace('<scale value="0.5"/></transform>', f'<scale value="0.5"/>{p}</transform>').replace('<translate y="-1"/></transform>', f'<translate y="-1"/>{p}</transform>') for p in places)
    return write(tmp_path, instanced, "i.xml"), write(tmp_path, flat, "f.xml")


def test_instances_expand_to_the_flat_scene(tmp_path):
    inst_path, flat_path = flat_and_instanced(tmp_path)
    inst, flat = ir.load_scene(inst_path), ir.load_scene(flat_path)
    assert inst.triangles.count == flat.triangles.count == 2 * (12 + 2)
    assert torch.allclose(inst.triangles.p0, flat.triangles.p0, atol=1e-6)
    # the first instance's cube: [-0.5, 0.5]^3 moved to x = -1.5
    cube = inst.triangles.corners()[:12].reshape(-1, 3)
    assert cube.min(0).values.tolist() == pytest.approx([-2.0, -0.5, -0.5]) and cube.max(0).values.tolist() == pytest.approx([-1.0, 0.5, 0.5])
    assert inst.materials == ("red", "material_1")  # a group's shapes are converted once: one default BSDF for both copies
    a, b = ir.render(inst, spp=8, seed=3), ir.render(flat, spp=8, seed=3)
    assert torch.allclose(a, b, atol=1e-5)


def test_instanced_triangles_are_limited(tmp_path, monkeypatch):
    inst_path, _ = flat_and_instanced(tmp_path)
    monkeypatch.setattr(instances, "MAX_INSTANCED_TRIANGLES", 20)
    with pytest.raises(SceneError) as info:
        ir.load_scene(inst_path)
    assert "\n" not in str(info.value) and "instances expand to more than 20 triangles (28 so far)" in str(info.value)


RECTANGLE = '<shape type="rectangle"><bsdf type="diffuse">{}</bsdf></shape>'
BAD = {
    "wrap mode": (RECTANGLE.format('<texture type="bitmap" name="reflectance"><string name="filename" value="t.exr"/>\n<string name="wrap_mode" value="border"/></texture>'),
                  "wrap_mode 'border' is not supported (supported: repeat, clamp, mirror)"),
    "filter type": (RECTANGLE.format('<texture type="bitmap" name="reflectance"><string name="filename" value="t.exr"/>\n<string name="filter_type" value="bicubic"/></texture>'),
                    "filter_type 'bicubic' is not supported (supported: bilinear, nearest)"),
    "attribute without a name": (RECTANGLE.format('\n<texture type="mesh_attribute" name="reflectance"/>'), 'missing <string name="name">'),
    "unprefixed attribute": (RECTANGLE.format('<texture type="mesh_attribute" name="reflectance">\n<string name="name" value="color"/></texture>'), "mesh attribute 'color' is not supported (supported: vertex_color, vertex_<x>, face_color, face_<x>)"),
    "unknown group": ('<shape type="instance">\n<ref id="nowhere"/></shape>', "reference to unknown id 'nowhere'"),
    "instance of a bsdf": ('<bsdf type="diffuse" id="b"/><shape type="instance">\n<ref id="b"/></shape><shape type="rectangle"/>', 'an instance refers to a shapegroup, got <bsdf type="diffuse">'),
    "emitting group": ('<shape type="shapegroup" id="g">\n<shape type="rectangle"><emitter type="area"/></shape></shape><shape type="instance"><ref id="g"/></shape>', "a shape in a shapegroup cannot emit"),
}


@pytest.mark.parametrize("name", BAD)
def test_bad_input_is_a_one_line_error(tmp_path, name):
    ir.write_image(tmp_path / "t.exr", TEXELS)
    body, words = BAD[name]
    path = write(tmp_path, "\n" + body)
    with pytest.raises(SceneError) as info:
        ir.load_scene(path)
    message = str(info.value)
    assert "\n" not in message and words in message, message
    line = next(i + 1 for i, text in enumerate(path.read_text().splitlines()) if text.startswith(body.split("\n")[1][:30]))
    assert message.startswith(f"{path}:{line}: "), message


def test_missing_attribute_and_bad_options(tmp_path):
    write_ply(tmp_path / "q.ply", COLOURS, extra=False)
    body = """<shape type="ply"><string name="filename" value="q.ply"/><bsdf type="diffuse">
    <texture type="mesh_attribute" name="reflectance"><string name="name" value="vertex_foo"/></texture></bsdf></shape>"""
    with pytest.raises(SceneError) as info:
        ir.load_scene(write(tmp_path, body))
    assert "\n" not in str(info.value) and "reads vertex attribute 'vertex_foo', which a mesh using material 'material_1' lacks (it has: vertex_color)" in str(info.value)
    for bad, words in ((dict(filter="cubic"), "unknown texture filter 'cubic'"), (dict(wrap="border"), "unknown texture wrap mode 'border'"), (dict(to_uv=(1, 0)), "to_uv must be 6 finite numbers")):
        with pytest.raises(SceneError, match=words):
            TextureSampling(**bad)


def test_binary_ply_with_mitsubas_attribute_naming(tmp_path):
    # Mitsuba's own writer stores vertex_color as color_0, color_1, color_2 (binary); a property
    # with two fields is ignored (as Mitsuba ignores it), one field is a grey attribute
    names = ("x", "y", "z", "color_0", "color_1", "color_2", "uv_x", "uv_y", "w_0")
    rows = np.array([(-1, -1, 0, *COLOURS[0], 0, 0, 0.5), (1, -1, 0, *COLOURS[1], 1, 0, 0.6), (1, 1, 0, *COLOURS[2], 1, 1, 0.7), (-1, 1, 0, *COLOURS[3], 0, 1, 0.8)], dtype="<f4")
    head = "ply\nformat binary_little_endian 1.0\nelement vertex 4\n" + "".join(f"property float {n}\n" for n in names)
    head += "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
    faces = b"".join(np.uint8(3).tobytes() + np.array(f, dtype="<i4").tobytes() for f in ((0, 1, 2), (0, 2, 3)))
    (tmp_path / "b.ply").write_bytes(head.encode() + rows.tobytes() + faces)
    body = """<shape type="ply"><string name="filename" value="b.ply"/><bsdf type="diffuse">
    <texture type="mesh_attribute" name="reflectance"><string name="name" value="{}"/></texture></bsdf></shape>"""
    scene = ir.load_scene(write(tmp_path, body.format("vertex_color")))
    assert torch.allclose(scene.params["material_1.reflectance"], torch.tensor(COLOURS))
    grey = ir.load_scene(write(tmp_path, body.format("vertex_w"), name="w.xml"))
    assert grey.params["material_1.reflectance"][:, 2].tolist() == pytest.approx([0.5, 0.6, 0.7, 0.8])
    with pytest.raises(SceneError, match="lacks \\(it has: vertex_color, vertex_w\\)"):
        ir.load_scene(write(tmp_path, body.format("vertex_uv"), name="uv.xml"))


@pytest.mark.parametrize("case", ["per vertex", "nearest mirror to_uv"])
def test_replay_equals_autodiff(tmp_path, case):
    """Both estimators differentiate a per-vertex parameter and a texture read with options alike
    (a closed box, so paths bounce between the textured walls)."""
    ir.write_image(tmp_path / "t.exr", TEXELS + 0.1)
    write_ply(tmp_path / "q.ply", COLOURS)
    texture = ('<texture type="mesh_attribute" name="reflectance"><string name="name" value="vertex_color"/></texture>' if case == "per vertex" else
               '<texture type="bitmap" name="reflectance"><string name="filename" value="t.exr"/><string name="filter_type" value="nearest"/>'
               '<string name="wrap_mode" value="mirror"/><transform name="to_uv"><scale x="1.7" y="2.2"/></transform></texture>')
    body = f"""<bsdf type="diffuse" id="m">{texture}</bsdf>
    <shape type="ply"><string name="filename" value="q.ply"/><ref id="m"/></shape>
    <shape type="ply"><string name="filename" value="q.ply"/><transform name="to_world"><rotate y="1" angle="90"/><translate x="-1"/></transform><ref id="m"/></shape>
    <shape type="sphere"><float name="radius" value="0.3"/><point name="center" x="0" y="0" z="1.5"/><emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>"""
    scene = ir.load_scene(write(tmp_path, body, w=12))
    value = scene.params["m.reflectance"].requires_grad_(True)
    grads = []
    for estimator in ("autodiff", "replay"):
        value.grad = None
        ir.render(scene, spp=4, max_depth=3, seed=5, estimator=estimator, progress=False).sum().backward()
        grads.append(value.grad.clone())
    assert grads[0].abs().sum() > 0 and torch.allclose(grads[0], grads[1], rtol=1e-4, atol=1e-6)
