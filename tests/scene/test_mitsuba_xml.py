"""Mitsuba 3 XML scene files: the supported subset, its mapping to invrender's scene, and one-line
errors with file and line for everything outside it."""

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

import invrender as ir
from invrender.cli import main
from invrender.errors import SceneError
from invrender.scene.builtin import cornell_box
from invrender.scene.formats.mitsuba import NAMED_IOR, load_mitsuba_xml
from tests.scene.conftest import SENSOR, write_scene

FORWARD = Path(__file__).parents[2] / "forward"

def write(tmp_path, body, name="s.xml", sensor=True):
    """A scene file: ``body`` inside <scene>, after a small sensor (line 1 is <scene>)."""
    return write_scene(tmp_path / name, body, sensor=sensor)


def line_of(path, text):
    """The 1-based line of the first line of ``path`` containing ``text``."""
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)


def material(scene, name):
    return scene.material_specs[scene.materials.index(name)]


# ---------------------------------------------------------------- the Cornell box


def test_cornell_box_xml_equals_builtin():
    a = cornell_box(resolution=(24, 24))
    b = ir.load_scene(FORWARD / "cornell_box.xml", resolution=(24, 24))
    assert b.triangles.count == a.triangles.count
    assert torch.allclose(a.triangles.corners(), b.triangles.corners(), atol=1e-5)
    assert torch.allclose(a.triangles.normal, b.triangles.normal, atol=1e-6)
    assert torch.equal(a.triangles.material, b.triangles.material) and torch.equal(a.triangles.emitter, b.triangles.emitter)
    assert a.materials == b.materials == ("white", "red", "green") and a.emitters == b.emitters == ("light",)
    assert [m.type for m in b.material_specs] == ["diffuse"] * 3
    assert a.params.keys() == b.params.keys() and all(torch.allclose(a.params[k], b.params[k]) for k in a.params)
    assert b.camera.origin == a.camera.origin and b.camera.fov == a.camera.fov and b.camera.fov_axis == a.camera.fov_axis
    assert all(torch.allclose(x, y, atol=1e-12) for x, y in zip(a.camera.frame(), b.camera.frame()))
    assert b.camera.is_pinhole and b.name == "cornell_box"
    image_a = ir.render(a, spp=4, max_depth=3, seed=0, progress=False)
    image_b = ir.render(b, spp=4, max_depth=3, seed=0, progress=False)
    assert torch.allclose(image_a, image_b, atol=1e-4)
    full = ir.load_scene(FORWARD / "cornell_box.xml")
    assert full.resolution == (256, 256) and full.defaults == {"spp": 64, "integrator": "path", "max_depth": 8}


# ---------------------------------------------------------------- BSDFs


def test_bsdfs_map_to_invrender_materials(tmp_path):
    path = write(tmp_path, """
    <bsdf type="conductor" id="mirror"><string name="material" value="none"/><rgb name="specular_reflectance" value="0.9, 0.8, 0.7"/></bsdf>
    <bsdf type="conductor" id="default_conductor"/>
    <bsdf type="roughconductor" id="glossy">
        <string name="distribution" value="ggx"/><float name="alpha" value="0.3"/>
        <string name="material" value="none"/><float name="specular_reflectance" value="0.6"/>
    </bsdf>
    <bsdf type="dielectric" id="glass"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1.2"/></bsdf>
    <bsdf type="dielectric" id="water"><string name="int_ior" value="water"/><string name="ext_ior" value="air"/></bsdf>
    <bsdf type="dielectric" id="bk7"/>
    <bsdf type="twosided" id="paper"><bsdf type="diffuse"><spectrum name="reflectance" value="0.25"/></bsdf></bsdf>
    <bsdf type="diffuse" id="grey"><float name="reflectance" value="0.4"/></bsdf>
    <bsdf type="diffuse" id="unused"/>
""" + "".join(f'<shape type="rectangle"><ref id="{m}"/></shape>' for m in ("mirror", "default_conductor", "glossy", "glass", "water", "bk7", "paper", "grey"))
        + '<shape type="cube"/>')
    scene = load_mitsuba_xml(path)
    assert scene.materials == ("mirror", "default_conductor", "glossy", "glass", "water", "bk7", "paper", "grey", "material_1")
    types = {name: material(scene, name).type for name in scene.materials}
    assert types == {"mirror": "mirror", "default_conductor": "mirror", "glossy": "glossy", "glass": "dielectric", "water": "dielectric",
                     "bk7": "dielectric", "paper": "diffuse", "grey": "diffuse", "material_1": "diffuse"}  # fmt: skip
    p = {k: v.tolist() for k, v in scene.params.items()}
    assert p["mirror.specular_reflectance"] == pytest.approx([0.9, 0.8, 0.7]) and p["default_conductor.specular_reflectance"] == [1, 1, 1]
    assert p["glossy.specular_reflectance"] == pytest.approx([0.6] * 3) and p["glossy.roughness"] == pytest.approx([0.3] * 3)
    assert material(scene, "glass").constants["ior"] == pytest.approx(1.25)
    assert material(scene, "water").constants["ior"] == pytest.approx(1.3330 / 1.000277)
    assert material(scene, "bk7").constants["ior"] == pytest.approx(1.5046 / 1.000277)  # Mitsuba's defaults
    assert p["paper.reflectance"] == pytest.approx([0.25] * 3) and p["grey.reflectance"] == pytest.approx([0.4] * 3)
    assert p["material_1.reflectance"] == [0.5] * 3  # a shape without a BSDF: Mitsuba's default diffuse
    assert NAMED_IOR["diamond"] == 2.419 and NAMED_IOR["fused quartz"] == 1.458 and NAMED_IOR["vacuum"] == 1.0 and len(NAMED_IOR) == 23


def test_bitmap_texture_lands_where_mitsuba_puts_it(tmp_path):
    """Mitsuba's rectangle has uv (0, 0) at its (-1, -1) corner and reads v = 0 at the image's top row."""
    pixels = np.zeros((2, 2, 3), dtype=np.uint8)
    pixels[0, 0] = (255, 0, 0)  # top-left red
    Image.fromarray(pixels).save(tmp_path / "tex.png")
    path = write(tmp_path, """
    <texture type="bitmap" id="tex"><string name="filename" value="tex.png"/></texture>
    <shape type="rectangle" id="floor">
        <bsdf type="diffuse"><ref name="reflectance" id="tex"/></bsdf>
    </shape>
    <shape type="rectangle">
        <bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="tex.png"/></texture></bsdf>
    </shape>""")
    scene = load_mitsuba_xml(path)
    texture = scene.params["floor_bsdf.reflectance"]
    assert texture.shape == (2, 2, 3) and torch.allclose(texture, ir.read_image(tmp_path / "tex.png"))
    assert torch.equal(texture, scene.params["material_1.reflectance"])
    corners, uv = scene.triangles.corners()[0], scene.triangles.uv[0]
    at = {tuple(c[:2].round().tolist()): tuple(u.tolist()) for c, u in zip(corners, uv)}
    assert at[(-1.0, -1.0)] == (0.0, 1.0) and at[(1.0, 1.0)] == (1.0, 0.0)  # invrender's v = 1 - Mitsuba's v


def test_conductors_named_metals_eta_k_and_beckmann(tmp_path):
    """Mitsuba's conductors as scene files write them: roughconductor without a distribution is
    Beckmann, named metals take the RGB eta/k of Mitsuba's RGB variants, eta/k given explicitly
    (defaults 0 and 1, as Mitsuba's), material none is Fresnel 1 (no eta/k constants set)."""
    path = write(tmp_path, """
    <bsdf type="roughconductor" id="rough_default"/>
    <bsdf type="roughconductor" id="rough_gold"><string name="material" value="Au"/><float name="alpha" value="0.25"/></bsdf>
    <bsdf type="roughconductor" id="rough_ggx"><string name="distribution" value="GGX"/><rgb name="eta" value="0.2, 0.9, 1.1"/></bsdf>
    <bsdf type="conductor" id="copper"><string name="material" value="Cu"/></bsdf>
    <bsdf type="conductor" id="given"><spectrum name="k" value="3"/></bsdf>
    <bsdf type="twosided" id="plain"><bsdf type="conductor"><string name="material" value="none"/></bsdf></bsdf>
""" + "".join(f'<shape type="rectangle"><ref id="{m}"/></shape>' for m in ("rough_default", "rough_gold", "rough_ggx", "copper", "given", "plain")))
    scene = load_mitsuba_xml(path)
    m = {name: material(scene, name) for name in scene.materials}
    assert {k: v.type for k, v in m.items()} == {"rough_default": "glossy_beckmann", "rough_gold": "glossy_beckmann", "rough_ggx": "glossy",
                                                 "copper": "mirror", "given": "mirror", "plain": "mirror"}  # fmt: skip
    roughness = {k: v.tolist() for k, v in scene.params.items() if k.endswith(".roughness")}
    assert roughness["rough_default.roughness"] == pytest.approx([0.1] * 3) and roughness["rough_gold.roughness"] == pytest.approx([0.25] * 3)
    # Mitsuba 3.9.1 scalar_rgb, mi.traverse(conductor material=Au / Cu): eta.value, k.value
    assert m["rough_gold"].constants["eta"] == pytest.approx((0.143036, 0.375307, 1.44205), rel=1e-5)
    assert m["rough_gold"].constants["k"] == pytest.approx((3.983, 2.38556, 1.60336), rel=1e-5)
    assert m["copper"].constants["eta"] == pytest.approx((0.201005, 0.92375, 1.10222), rel=1e-5)
    assert m["copper"].constants["k"] == pytest.approx((3.91326, 2.45305, 2.14209), rel=1e-5)
    assert m["rough_ggx"].constants["eta"] == pytest.approx((0.2, 0.9, 1.1)) and m["rough_ggx"].constants["k"] == (1.0, 1.0, 1.0)
    assert m["given"].constants["eta"] == (0.0, 0.0, 0.0) and m["given"].constants["k"] == (3.0, 3.0, 3.0)
    for name in ("rough_default", "plain"):
        assert m[name].constants["eta"] == (0.0, 0.0, 0.0) and m[name].constants["k"] == (1.0, 1.0, 1.0)


def test_checkerboard_cells_are_mitsubas(tmp_path):
    """Mitsuba's checkerboard: color0 where frac(s) > 0.5 and frac(t) > 0.5 agree, (s, t) = to_uv (u, v),
    v = 0 at the image's top row; baked at 512 x 512, a to_uv scale of 2 makes 4 x 4 cells of 128 texels."""
    path = write(tmp_path, """
    <shape type="rectangle" id="floor"><bsdf type="diffuse">
        <texture type="checkerboard" name="reflectance"><rgb name="color0" value="0.9, 0.1, 0.1"/><float name="color1" value="0.3"/>
            <transform name="to_uv"><scale x="2" y="2"/></transform></texture>
    </bsdf></shape>
    <shape type="rectangle" id="wall"><bsdf type="diffuse">
        <texture type="checkerboard" name="reflectance"><transform name="to_uv"><translate x="0.5"/></transform></texture>
    </bsdf></shape>""")
    scene = load_mitsuba_xml(path)
    board = scene.params["floor_bsdf.reflectance"]
    assert board.shape == (512, 512, 3)
    red, grey = torch.tensor([0.9, 0.1, 0.1]), torch.tensor([0.3] * 3)
    for i in range(4):  # cell rows (Mitsuba's v, from the top) and columns (u)
        for j in range(4):
            cell = board[128 * i:128 * (i + 1), 128 * j:128 * (j + 1)].reshape(-1, 3)
            expected = red if (i + j) % 2 == 0 else grey  # the cell at uv = 0 (top left) is color0
            assert torch.allclose(cell, expected.expand_as(cell)), (i, j)
    wall = scene.params["wall_bsdf.reflectance"]  # defaults 0.4 / 0.2, shifted half a period in u: the top-left cell is color1
    assert float(wall[0, 0, 0]) == pytest.approx(0.2) and float(wall[0, 511, 0]) == pytest.approx(0.4)
    assert float(wall[511, 0, 0]) == pytest.approx(0.4) and float(wall[511, 511, 0]) == pytest.approx(0.2)


# ---------------------------------------------------------------- shapes and transforms


def test_sphere_center_radius_and_tessellation(tmp_path):
    path = write(tmp_path, """
    <shape type="sphere"><point name="center" x="1" y="2" z="3"/><float name="radius" value="0.5"/></shape>""")
    scene = load_mitsuba_xml(path)
    tris = scene.triangles
    assert tris.count == 20 * 4**5 and bool(tris.smooth.all())
    distance = (tris.corners().reshape(-1, 3).double() - torch.tensor([1.0, 2, 3], dtype=torch.float64)).norm(dim=1)
    assert torch.allclose(distance, torch.full_like(distance, 0.5), atol=1e-5)
    assert load_mitsuba_xml(path, sphere_subdivisions=1).triangles.count == 80


def test_named_references_and_flip_normals(tmp_path):
    """Exporters (e.g. mitsuba-blender) name nested objects: ``<ref name="bsdf" id=.../>``."""
    path = write(tmp_path, """
    <bsdf type="diffuse" id="m"><float name="reflectance" value="0.3"/></bsdf>
    <shape type="rectangle"><ref name="bsdf" id="m"/></shape>
    <shape type="rectangle"><boolean name="flip_normals" value="true"/><bsdf type="diffuse" name="bsdf"/></shape>""")
    scene = load_mitsuba_xml(path)
    assert scene.materials == ("m", "material_1") and scene.triangles.material.tolist() == [0, 0, 1, 1]
    assert scene.triangles.normal[:2, 2].tolist() == [1, 1] and scene.triangles.normal[2:, 2].tolist() == [-1, -1]


def test_transforms_apply_in_document_order(tmp_path):
    path = write(tmp_path, """
    <shape type="rectangle">
        <transform name="to_world"><scale value="2"/><rotate z="1" angle="90"/><translate x="10"/></transform>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><matrix value="0 -2 0 10  2 0 0 0  0 0 2 0  0 0 0 1"/></transform>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><rotate z="2" angle="90"/><translate value="10 0 0"/></transform>
    </shape>""")
    with pytest.warns(UserWarning, match="not a unit vector"):  # Mitsuba 3 does not normalize it: 90 degrees and x2
        corners = load_mitsuba_xml(path).triangles.corners()
    expected = torch.tensor([[[12.0, -2, 0], [12, 2, 0], [8, 2, 0]], [[12, -2, 0], [8, 2, 0], [8, -2, 0]]])
    for i in range(3):
        assert torch.allclose(corners[2 * i : 2 * i + 2], expected, atol=1e-5), i


def test_obj_and_ply_files(tmp_path):
    mesh = trimesh.creation.icosphere(1)
    normals = -np.asarray(mesh.vertex_normals)  # not what trimesh would compute: proves the file's are used
    with_normals = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_normals=normals, process=False)
    with_normals.export(tmp_path / "n.ply", vertex_normal=True)
    (tmp_path / "n.obj").write_text(trimesh.exchange.obj.export_obj(with_normals, include_normals=True))
    (tmp_path / "p.obj").write_text(trimesh.exchange.obj.export_obj(mesh, include_normals=False))
    path = write(tmp_path, """
    <shape type="ply" id="a"><string name="filename" value="n.ply"/><transform name="to_world"><translate x="3"/></transform></shape>
    <shape type="obj" id="b"><string name="filename" value="n.obj"/></shape>
    <shape type="obj" id="c"><string name="filename" value="n.obj"/><boolean name="face_normals" value="true"/></shape>
    <shape type="obj" id="d"><string name="filename" value="p.obj"/></shape>""")
    scene = load_mitsuba_xml(path)
    tris = scene.triangles
    per_shape = [tris.material == scene.materials.index(f"{s}_bsdf") for s in "abcd"]
    assert [int(m.sum()) for m in per_shape] == [80] * 4
    expected = torch.as_tensor(normals[mesh.faces], dtype=torch.float32)
    assert torch.allclose(tris.vertex_normal[per_shape[0]], expected, atol=1e-5) and bool(tris.smooth[per_shape[0]].all())
    assert torch.allclose(tris.vertex_normal[per_shape[1]], expected, atol=1e-5)
    assert not bool(tris.smooth[per_shape[2]].any())  # face_normals: flat
    computed = tris.vertex_normal[per_shape[3]]  # no normals in the file: computed (outwards here)
    assert bool(tris.smooth[per_shape[3]].all()) and bool(((computed * tris.corners()[per_shape[3]]).sum(-1) > 0.9).all())
    assert torch.allclose(tris.p0[per_shape[0]] - torch.tensor([3.0, 0, 0]), tris.p0[per_shape[1]], atol=1e-6)


def test_obj_texture_coordinates_follow_flip_tex_coords(tmp_path):
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0.1 0.2\nvt 0.3 0.4\nvt 0.5 0.6\nf 1/1 2/2 3/3\n")
    path = write(tmp_path, """
    <shape type="obj"><string name="filename" value="t.obj"/></shape>
    <shape type="obj"><string name="filename" value="t.obj"/><boolean name="flip_tex_coords" value="false"/></shape>""")
    uv = load_mitsuba_xml(path).triangles.uv
    assert torch.allclose(uv[0], torch.tensor([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]]))  # as written (Mitsuba flips twice)
    assert torch.allclose(uv[1], torch.tensor([[0.1, 0.8], [0.3, 0.6], [0.5, 0.4]]))


# ---------------------------------------------------------------- sensor, parameters, references, names


def test_thinlens_sensor_and_film(tmp_path):
    path = tmp_path / "cam.xml"
    path.write_text("""<scene version="3.0.0">
    <sensor type="thinlens">
        <float name="fov" value="30"/><string name="fov_axis" value="y"/>
        <float name="aperture_radius" value="0.1"/><float name="focus_distance" value="2.5"/>
        <transform name="to_world"><scale value="2"/><rotate y="1" angle="180"/><translate z="5"/></transform>
        <sampler type="stratified"><integer name="sample_count" value="16"/></sampler>
        <film type="hdrfilm"><integer name="width" value="20"/><integer name="height" value="10"/><rfilter type="box"/></film>
    </sensor>
    <integrator type="path"><integer name="max_depth" value="-1"/><integer name="rr_depth" value="3"/></integrator>
    <shape type="rectangle"/>
</scene>""")
    scene = load_mitsuba_xml(path)
    cam = scene.camera
    assert cam.aperture_radius == pytest.approx(0.2) and cam.focus_distance == pytest.approx(5.0)  # scaled by to_world
    assert cam.fov == 30 and cam.fov_axis == "y" and scene.resolution == (20, 10)
    right, up, forward = cam.frame()
    assert np.allclose(cam.origin, (0, 0, 5)) and torch.allclose(forward, torch.tensor([0.0, 0, -1], dtype=torch.float64), atol=1e-12)
    assert torch.allclose(right, torch.tensor([1.0, 0, 0], dtype=torch.float64), atol=1e-12)  # image x is Mitsuba's local -x
    assert scene.defaults == {"spp": 16, "integrator": "path", "max_depth": -1, "rr_depth": 3}
    assert load_mitsuba_xml(path, resolution=(4, 2)).resolution == (4, 2)


def test_defaults_parameters_and_references(tmp_path):
    path = tmp_path / "p.xml"
    path.write_text("""<scene version="3.0.0">
    <default name="r" value="0.2"/>
    <default name="rg" value="0.9"/>
    <default name="r" value="0.7"/>""" + SENSOR + """
    <shape type="rectangle"><ref id="later"/></shape>
    <shape type="rectangle" id="lamp"><ref id="later"/>
        <emitter type="area"><rgb name="radiance" value="$r, $rg, 1"/></emitter></shape>
    <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="2"/></emitter></shape>
    <shape type="rectangle"><emitter type="area"/></shape>
    <bsdf type="diffuse" id="later"><rgb name="reflectance" value="$r"/></bsdf>
</scene>""")
    scene = load_mitsuba_xml(path)
    assert scene.materials == ("material_1", "material_2", "later")  # in the order the BSDFs (or their shapes) appear
    assert torch.allclose(scene.params["later.reflectance"], torch.full((3,), 0.2))  # the first <default> of a name wins
    assert scene.emitters == ("lamp", "emitter", "emitter_2")
    assert torch.allclose(scene.params["lamp.emission"], torch.tensor([0.2, 0.9, 1.0]))  # $rg is not $r + "g"
    assert scene.params["emitter.emission"].tolist() == [2, 2, 2] and scene.params["emitter_2.emission"].tolist() == [1, 1, 1]
    assert scene.triangles.material.tolist() == [2, 2, 2, 2, 0, 0, 1, 1]  # the first two shapes share the referenced BSDF
    overridden = load_mitsuba_xml(path, parameters={"r": 0.5})
    assert torch.allclose(overridden.params["later.reflectance"], torch.full((3,), 0.5))


def test_names_are_unique_and_never_ambient(tmp_path):
    path = write(tmp_path, """
    <bsdf type="diffuse" id="ambient"/>
    <shape type="rectangle" id="wall"><ref id="ambient"/></shape>
    <shape type="rectangle" id="panel"><emitter type="area"/></shape>
    <bsdf type="diffuse" id="panel_bsdf"/>
    <shape type="cube"><ref id="panel_bsdf"/></shape>""")
    scene = load_mitsuba_xml(path)
    assert scene.materials == ("ambient_2", "panel_bsdf_2", "panel_bsdf") and scene.emitters == ("panel",)


def _with_film(tmp_path, film_inside: str):
    path = write(tmp_path, '<shape type="rectangle"/>', sensor=False)
    path.write_text(path.read_text().replace("<shape", SENSOR.replace("<film type=\"hdrfilm\">", f'<film type="hdrfilm">{film_inside}') + "<shape"))
    return path


def test_rfilter_and_film_options_load(tmp_path):
    """Each <rfilter> with its settings; Mitsuba's default (gaussian, stddev 0.5) without one;
    sample_border; bad settings are one-line errors naming the line."""
    scene = load_mitsuba_xml(_with_film(tmp_path, '<rfilter type="gaussian"><float name="stddev" value="0.3"/></rfilter><boolean name="sample_border" value="true"/>'))
    f = scene.film.filter
    assert f.type_name == "gaussian" and f.stddev == 0.3 and f.radius == pytest.approx(1.2) and scene.film.sample_border
    assert load_mitsuba_xml(_with_film(tmp_path, "")).film.filter.type_name == "gaussian"  # hdrfilm's default
    assert load_mitsuba_xml(_with_film(tmp_path, "")).film.filter.stddev == 0.5
    assert load_mitsuba_xml(_with_film(tmp_path, '<rfilter type="box"/>')).film.is_box
    m = load_mitsuba_xml(_with_film(tmp_path, '<rfilter type="mitchell"><float name="B" value="0.5"/></rfilter>')).film.filter
    assert (m.B, m.C, m.radius) == (0.5, pytest.approx(1 / 3), 2.0)
    assert load_mitsuba_xml(_with_film(tmp_path, '<rfilter type="lanczos"><integer name="lobes" value="2"/></rfilter>')).film.filter.radius == 2.0
    for inside, match in (
        ('<rfilter type="gaussian"><float name="stddev" value="-1"/></rfilter>', "stddev must be a number in"),
        ('<rfilter type="tent"><float name="radius" value="1e6"/></rfilter>', "radius must be a number in"),
        ('<rfilter type="gaussian"><float name="radius" value="2"/></rfilter>', "unsupported property 'radius'"),
        ('<rfilter type="sinc"/>', "unsupported rfilter type 'sinc'"),
        ('<integer name="crop_offset_x" value="15"/><integer name="crop_width" value="10"/>', "crop window"),
    ):
        with pytest.raises(SceneError, match=match) as e:
            load_mitsuba_xml(_with_film(tmp_path, inside))
        assert "\n" not in str(e.value)


def test_load_scene_dispatch_and_cli_defaults(tmp_path, capsys):
    path = write(tmp_path, '<shape type="rectangle"/>', sensor=False)
    path.write_text(path.read_text().replace("<shape", SENSOR.replace("</sensor>", '<sampler type="independent"><integer name="sample_count" value="3"/></sampler></sensor>') + "<shape"))
    assert ir.load_scene(str(path)).defaults == {"spp": 3}
    out = tmp_path / "o.exr"
    assert main(["render", str(path), "--out", str(out)]) == 0 and out.is_file()
    assert ", 3 spp," in capsys.readouterr().err
    assert main(["render", str(path), "--spp", "2", "--out", str(out)]) == 0 and ", 2 spp," in capsys.readouterr().err
    with pytest.raises(SceneError, match=r"\.xml"):
        ir.load_scene(tmp_path / "scene.mtsxml")


# ---------------------------------------------------------------- errors


BAD = {
    # name: (body, text on the offending line, words in the message)
    "unknown element": ('<shape type="rectangle"><colour name="x" value="1"/></shape>', "<colour", "unknown element <colour>"),
    "unsupported shape": ('<shape type="hair"/>', "hair", "unsupported shape type 'hair' (supported: rectangle, cube, sphere, disk, cylinder, obj, ply, serialized)"),
    "unsupported bsdf": ('<shape type="rectangle"><bsdf type="hair"/></shape>', "hair", "unsupported bsdf type 'hair'"),
    "unsupported emitter": ('<shape type="rectangle"/>\n<emitter type="sunsky"/>', "sunsky", "unsupported emitter type 'sunsky' (supported: area"),
    "emitter in shape": ('<shape type="rectangle"><emitter type="spot"/></shape>', "spot", "an emitter of type 'spot' is a point or a direction (a delta light), not emitted by a shape"),
    # conductors: named metals, eta/k and Beckmann load (test_conductors_...); what stays outside the subset
    "conductor material": ('<shape type="rectangle"><bsdf type="conductor">\n<string name="material" value="Unobtainium"/></bsdf></shape>', "Unobtainium", "unknown conductor material 'Unobtainium' (known: none, a-C, Ag, Al,"),
    "conductor material and eta": ('<shape type="rectangle"><bsdf type="conductor"><string name="material" value="Au"/>\n<rgb name="eta" value="0.2"/></bsdf></shape>', "eta", "give either material 'Au' or 'eta', not both"),
    "negative k": ('<shape type="rectangle"><bsdf type="roughconductor">\n<rgb name="k" value="1, -2, 3"/></bsdf></shape>', "1, -2, 3", "'k' (the complex index of refraction's imaginary part) must be >= 0, got 1, -2, 3"),
    "textured eta": ('<shape type="rectangle"><bsdf type="conductor">\n<texture type="checkerboard" name="eta"/></bsdf></shape>', "checkerboard", "'eta' must be an <rgb>, a <float> or a constant <spectrum>"),
    "unknown distribution": ('<shape type="rectangle"><bsdf type="roughconductor">\n<string name="distribution" value="phong"/></bsdf></shape>', "phong", "distribution 'phong' is not supported (supported: beckmann, ggx)"),
    "beckmann roughness 0": ('<shape type="rectangle"><bsdf type="roughconductor">\n<float name="alpha" value="0"/></bsdf></shape>', "alpha", "'alpha' (Beckmann roughness) must lie in (0, 1], got 0"),
    "checkerboard nested texture": ('<shape type="rectangle"><bsdf type="diffuse"><texture type="checkerboard" name="reflectance">\n<texture type="bitmap" name="color0"/></texture></bsdf></shape>', "color0", "'color0' must be an <rgb>, a <float> or a constant <spectrum> (nested textures are not supported)"),
    "checkerboard specular": ('<shape type="rectangle"><bsdf type="conductor">\n<texture type="checkerboard" name="specular_reflectance"/></bsdf></shape>', "checkerboard", "'specular_reflectance' must be a constant"),
    "checkerboard colour range": ('<shape type="rectangle"><bsdf type="diffuse"><texture type="checkerboard" name="reflectance">\n<rgb name="color1" value="2"/></texture></bsdf></shape>', "checkerboard", "'reflectance' (diffuse albedo rho) must lie in [0, 1], got values in [0.4, 2]"),
    "alpha_u": ('<shape type="rectangle"><bsdf type="roughconductor"><string name="distribution" value="ggx"/>\n<float name="alpha_v" value="0.2"/></bsdf></shape>', "alpha_v", "'alpha_v' needs 'alpha_u' too"),
    "roughness 0": ('<shape type="rectangle"><bsdf type="roughconductor"><string name="distribution" value="ggx"/>\n<float name="alpha" value="0"/></bsdf></shape>', "alpha", "'alpha' (GGX roughness) must lie in (0, 1], got 0"),
    "roughness 1.5": ('<shape type="rectangle"><bsdf type="roughconductor"><string name="distribution" value="ggx"/>\n<float name="alpha" value="1.5"/></bsdf></shape>', "alpha", "got 1.5"),
    "negative ior": ('<shape type="rectangle"><bsdf type="dielectric">\n<float name="int_ior" value="-1.5"/></bsdf></shape>', "int_ior", "'int_ior' must be positive, got -1.5"),
    "unknown ior name": ('<shape type="rectangle"><bsdf type="dielectric">\n<string name="ext_ior" value="oil"/></bsdf></shape>', "oil", "unknown ext_ior 'oil' (known: vacuum"),
    "reflectance 1.5": ('<shape type="rectangle"><bsdf type="diffuse">\n<rgb name="reflectance" value="0.5, 1.5, 0.5"/></bsdf></shape>', "1.5", "'reflectance' (diffuse albedo rho) must lie in [0, 1], got 0.5, 1.5, 0.5"),
    "negative radiance": ('<shape type="rectangle"><emitter type="area">\n<rgb name="radiance" value="-1"/></emitter></shape>', "-1", "must be >= 0, got -1, -1, -1"),
    "unknown parameter": ('<shape type="rectangle"><bsdf type="diffuse">\n<float name="reflectance" value="$y"/></bsdf></shape>', "$y", "undefined parameter $y"),
    "missing obj": ('<shape type="obj">\n<string name="filename" value="missing.obj"/></shape>', "missing.obj", "mesh file not found"),
    "unsupported property": ('<shape type="rectangle"><bsdf type="diffuse">\n<float name="roughness" value="0.1"/></bsdf></shape>', "roughness", "unsupported property 'roughness' (supported: reflectance)"),
    "unknown ref": ('<shape type="rectangle">\n<ref id="nowhere"/></shape>', "nowhere", "reference to unknown id 'nowhere'"),
    "duplicate id": ('<bsdf type="diffuse" id="x"/>\n<bsdf type="diffuse" id="x"/><shape type="rectangle"/>', 'id="x"/><shape', "duplicate id 'x' (first used at line"),
    "two bsdfs": ('<shape type="rectangle"><bsdf type="diffuse"/>\n<bsdf type="diffuse"/></shape>', '<bsdf type="diffuse"/></shape>', "only one <bsdf> per <shape"),
    "twosided dielectric": ('<shape type="rectangle"><bsdf type="twosided">\n<bsdf type="dielectric"/></bsdf></shape>', "dielectric", "twosided cannot wrap a dielectric"),
    "twosided roughdielectric": ('<shape type="rectangle"><bsdf type="twosided">\n<bsdf type="roughdielectric"/></bsdf></shape>', "roughdielectric", "twosided cannot wrap a roughdielectric"),
    "twosided thindielectric": ('<shape type="rectangle"><bsdf type="twosided">\n<bsdf type="thindielectric"/></bsdf></shape>', "thindielectric", "twosided cannot wrap a thindielectric"),
    "bad number": ('<shape type="sphere">\n<float name="radius" value="big"/></shape>', "big", "could not parse a number from 'big'"),
    "zero radius": ('<shape type="sphere">\n<float name="radius" value="0"/></shape>', "radius", "'radius' must be positive"),
    "bad transform op": ('<shape type="rectangle"><transform name="to_world">\n<shear value="1"/></transform></shape>', "shear", "a <transform> holds only translate"),
    "integrator": ('<shape type="rectangle"/>\n<integrator type="prb"/>', "prb", "unsupported integrator type 'prb' (supported: path, direct)"),
    "max_depth 0": ('<shape type="rectangle"/><integrator type="path">\n<integer name="max_depth" value="0"/></integrator>', "max_depth", "'max_depth' must be >= 1, or -1"),
    "include": ('\n<include filename="other.xml"/><shape type="rectangle"/>', "include", "included file not found: 'other.xml'"),
    "text": ('<shape type="rectangle">\nhello</shape>', "hello", "unexpected text 'hello'"),
}

SENSOR_BAD = {
    "negative aperture": ('<float name="fov" value="40"/>\n<float name="aperture_radius" value="-0.1"/>', "thinlens", "aperture_radius", "'aperture_radius' must be >= 0, got -0.1"),
    "zero focus distance": ('<float name="fov" value="40"/><float name="aperture_radius" value="0.1"/>\n<float name="focus_distance" value="0"/>', "thinlens", "focus_distance", "'focus_distance' must be positive, got 0"),
    "diagonal fov_axis": ('<float name="fov" value="40"/>\n<string name="fov_axis" value="diagonal"/>', "perspective", "diagonal", "fov_axis 'diagonal' is not supported (supported: x, y, smaller, larger)"),
    "sensor type": ('<float name="fov" value="40"/>', "radiancemeter", "radiancemeter", "unsupported sensor type 'radiancemeter' (supported: perspective, thinlens, orthographic)"),
    "bad focal length": ('<string name="focal_length" value="fifty"/>', "perspective", "focal_length", "'focal_length' 'fifty' must be a positive length in millimetres"),
    "fov and focal length": ('<float name="fov" value="40"/>\n<string name="focal_length" value="35mm"/>', "perspective", "focal_length", "give either 'fov' or 'focal_length', not both"),
    "mirrored": ('<float name="fov" value="40"/><transform name="to_world">\n<scale x="-1"/></transform>', "perspective", "<transform", "mirrored"),
    "film type": ('<float name="fov" value="40"/>\n<film type="specfilm"/>', "perspective", "specfilm", "unsupported film type 'specfilm' (supported: hdrfilm)"),
}


def check_one_line_error(path, line, words):
    with pytest.raises(SceneError) as info:
        ir.load_scene(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}:{line}: "), message
    assert words in message, message


@pytest.mark.parametrize("name", BAD)
def test_outside_the_subset_is_a_one_line_error_with_line(tmp_path, name):
    body, marker, words = BAD[name]
    path = write(tmp_path, "\n" + body)
    check_one_line_error(path, line_of(path, marker), words)


@pytest.mark.parametrize("name", SENSOR_BAD)
def test_bad_sensors(tmp_path, name):
    inner, kind, marker, words = SENSOR_BAD[name]
    path = tmp_path / "s.xml"
    path.write_text(f'<scene version="3.0.0">\n<sensor type="{kind}">\n{inner}\n</sensor>\n<shape type="rectangle"/>\n</scene>\n')
    check_one_line_error(path, line_of(path, marker), words)


def test_malformed_xml_and_root(tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text('<scene version="3.0.0">\n<shape type="rectangle">\n</scene>\n')
    check_one_line_error(path, 3, "malformed XML: mismatched tag")
    path.write_text('<scene>\n<shape type="rectangle"/>\n</scene>\n')
    check_one_line_error(path, 1, "missing attribute 'version'")
    path.write_text('<scene version="3.0.0">\n<shape type="rectangle"/>\n</scene>\n')
    check_one_line_error(path, 1, "no <sensor>")


def test_cli_reports_one_line_and_writes_nothing(tmp_path, capsys):
    path = write(tmp_path, '\n<shape type="rectangle"><bsdf type="diffuse">\n<rgb name="reflectance" value="1.5"/></bsdf></shape>')
    out = tmp_path / "x.exr"
    assert main(["render", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"invrender: error: {path}:{line_of(path, '1.5')}: <bsdf type=\"diffuse\">")
    assert not out.exists()


def test_crop_window_renders_the_crop_with_the_full_films_projection(tmp_path):
    full = load_mitsuba_xml(_with_film(tmp_path, ""))
    inside = '<integer name="crop_offset_x" value="2"/><integer name="crop_offset_y" value="1"/><integer name="crop_width" value="4"/><integer name="crop_height" value="3"/>'
    crop = load_mitsuba_xml(_with_film(tmp_path, inside))
    assert full.resolution == (8, 6) and crop.resolution == (4, 3)
    xy = torch.rand(32, 2) * torch.tensor([4.0, 3.0])
    assert torch.allclose(full.camera.generate_rays(xy + torch.tensor([2.0, 1.0]), 8, 6)[1], crop.camera.generate_rays(xy, 4, 3)[1], atol=1e-6)
    with pytest.warns(UserWarning, match="crop window of the 8x6 film is dropped"):
        assert ir.load_scene(_with_film(tmp_path, inside), resolution=(16, 12)).resolution == (16, 12)
