"""The Mitsuba 3 XML language beyond the plugins: search paths, includes, spectra, objects declared
at the top level and referenced, Mitsuba 0.x upgrades, and one error listing every problem.

Reference numbers marked "Mitsuba 3.9.1" were computed once with mitsuba 3.9.1 (``scalar_rgb``,
``mi.traverse`` of the same XML) and are hard-coded here: the tests do not need Mitsuba."""

import numpy as np
import pytest

from invrender.errors import SceneError
from invrender.scene.formats.mitsuba import load_mitsuba_xml
from invrender.scene.formats.mitsuba.parser import snake_case
from invrender.scene.formats.mitsuba.spectra import spectrum_to_srgb
from tests.scene.conftest import write_scene

def write(path, body, version="3.0.0", sensor=True):
    """A scene file at ``path``: ``body`` inside <scene> (line 1), after a small sensor."""
    return write_scene(path, body, version, sensor)


def line_of(path, text):
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)


def error_of(path) -> str:
    with pytest.raises(SceneError) as info:
        load_mitsuba_xml(path)
    message = str(info.value)
    assert "\n" not in message
    return message


def material(scene, name):
    return scene.material_specs[scene.materials.index(name)]


# ---------------------------------------------------------------- <path> and <include>


def test_path_and_include(tmp_path):
    """An included file's objects stand where the <include> is (its own defaults join the
    others, the first definition wins), relative to the including file; <path> folders are
    searched for files first."""
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    write(tmp_path / "parts" / "materials.xml", '<default name="albedo" value="0.3"/><default name="g" value="0.7"/>'
          '<bsdf type="diffuse" id="grey"><float name="reflectance" value="$albedo"/></bsdf><include filename="more/green.xml"/>', sensor=False)
    write(tmp_path / "parts" / "more" / "green.xml", '<bsdf type="diffuse" id="green"><rgb name="reflectance" value="0.1, $g, 0.1"/></bsdf>', sensor=False)
    main = write(tmp_path / "main.xml", """
    <path value="meshes"/>
    <default name="albedo" value="0.6"/>
    <include filename="parts/materials.xml"/>
    <shape type="obj"><string name="filename" value="tri.obj"/><ref id="grey"/></shape>
    <shape type="rectangle"><ref id="green"/></shape>""")
    scene = load_mitsuba_xml(main)
    assert scene.materials == ("grey", "green")
    assert scene.params["grey.reflectance"].tolist() == pytest.approx([0.6] * 3)  # main.xml's default came first
    assert scene.params["green.reflectance"].tolist() == pytest.approx([0.1, 0.7, 0.1])
    assert scene.triangles.material.tolist() == [0, 1, 1]  # tri.obj (found in the <path> folder), then the rectangle


def test_include_problems_name_file_and_line(tmp_path):
    a = write(tmp_path / "a.xml", '\n<include filename="b.xml"/><shape type="rectangle"/>')
    b = write(tmp_path / "b.xml", '\n<include filename="a.xml"/>', sensor=False)
    message = error_of(a)
    assert message.startswith(f"{b}:2: <include>: <include> cycle: a.xml -> b.xml -> a.xml"), message
    missing = write(tmp_path / "m.xml", '<shape type="rectangle"/>\n<include filename="nowhere.xml"/>')
    assert error_of(missing).startswith(f"{missing}:{line_of(missing, 'nowhere')}: <include>: included file not found: 'nowhere.xml'")
    folder = write(tmp_path / "p.xml", '<shape type="rectangle"/>\n<path value="no_such_folder"/>')
    assert error_of(folder).startswith(f"{folder}:{line_of(folder, 'no_such')}: <path>: folder not found: 'no_such_folder'")
    # an error inside an included file names that file and its line
    write(tmp_path / "bad.xml", '\n\n<bsdf type="diffuse" id="x"><float name="roughness" value="1"/></bsdf>', sensor=False)
    inc = write(tmp_path / "inc.xml", '<include filename="bad.xml"/><shape type="rectangle"><ref id="x"/></shape>')
    assert error_of(inc).startswith(f"{tmp_path / 'bad.xml'}:3: <bsdf type=\"diffuse\">: unsupported property 'roughness'")


def test_versions(tmp_path):
    newer = write(tmp_path / "n.xml", '<shape type="rectangle"/>', version="4.0.0")
    assert error_of(newer).startswith(f"{newer}:1: <scene>: version 4.0.0 is newer than the format invrender reads (Mitsuba 3")
    assert error_of(write(tmp_path / "v.xml", '<shape type="rectangle"/>', version="3.0")).endswith("version must be three numbers like 3.0.0, got '3.0'")


def test_mitsuba_0_files_are_upgraded(tmp_path):
    """Mitsuba 0.x names as Mitsuba 3's upgrade_tree renames them: camelCase to snake_case,
    <lookAt>, a diffuse's diffuseReflectance, ids with a leading underscore."""
    assert [snake_case(n) for n in ("intIOR", "toWorld", "diffuseReflectance", "maxDepth", "fov", "sampleCount", "aB")] == [
        "int_ior", "to_world", "diffuse_reflectance", "max_depth", "fov", "sample_count", "a_b"]  # fmt: skip
    path = tmp_path / "old.xml"
    path.write_text("""<scene version="0.5.0">
    <integrator type="path"><integer name="maxDepth" value="3"/></integrator>
    <sensor type="perspective"><float name="fov" value="40"/>
        <transform name="toWorld"><lookAt origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sampleCount" value="4"/></sampler>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film></sensor>
    <bsdf type="diffuse" id="_white"><rgb name="diffuseReflectance" value="0.2, 0.4, 0.6"/></bsdf>
    <bsdf type="dielectric" id="glass"><float name="intIOR" value="1.7"/></bsdf>
    <shape type="rectangle"><ref id="_white"/></shape>
    <shape type="sphere"><ref id="glass"/></shape>
</scene>""")
    scene = load_mitsuba_xml(path)
    assert scene.materials == ("ID_white__UPGR", "glass")
    assert scene.params["ID_white__UPGR.reflectance"].tolist() == pytest.approx([0.2, 0.4, 0.6])
    assert material(scene, "glass").constants["ior"] == pytest.approx(1.7 / 1.000277)
    assert scene.defaults["max_depth"] == 3 and scene.defaults["spp"] == 4


# ---------------------------------------------------------------- spectra


def test_spectra_convert_as_mitsubas_rgb_variants(tmp_path):
    """wavelength:value lists and .spd files, as Mitsuba 3.9.1 scalar_rgb converts them (mi.traverse
    of the same XML): reflectances with the D65 weighting and bounded, eta/k with it and
    unbounded, emitters' radiance without it."""
    (tmp_path / "s.spd").write_text("# test\n400 1\n500 5\n600 10\n700 20\n")
    path = write(tmp_path / "s.xml", """
    <bsdf type="diffuse" id="a"><spectrum name="reflectance" value="400:0.2, 500:0.4, 600:0.6, 700:0.8"/></bsdf>
    <bsdf type="diffuse" id="flat"><spectrum name="reflectance" value="400:0.5 500:0.5 600:0.5 700:0.5"/></bsdf>
    <bsdf type="diffuse" id="const"><spectrum name="reflectance" value="0.25"/></bsdf>
    <bsdf type="conductor" id="c"><spectrum name="eta" value="400:1, 500:5, 600:10, 700:20"/><spectrum name="k" filename="s.spd"/></bsdf>
    <shape type="rectangle"><ref id="a"/></shape><shape type="rectangle"><ref id="flat"/></shape>
    <shape type="rectangle"><ref id="const"/></shape><shape type="rectangle"><ref id="c"/></shape>
    <shape type="sphere" id="lamp"><emitter type="area"><spectrum name="radiance" filename="s.spd"/></emitter></shape>""")
    scene = load_mitsuba_xml(path)
    p = {k: v.tolist() for k, v in scene.params.items()}
    assert p["a.reflectance"] == pytest.approx([0.681557, 0.485825, 0.280607], rel=1e-4)  # Mitsuba 3.9.1
    assert p["flat.reflectance"] == pytest.approx([0.497671, 0.499878, 0.497455], rel=1e-4)  # Mitsuba 3.9.1
    assert p["const.reflectance"] == [0.25] * 3
    assert material(scene, "c").constants["eta"] == pytest.approx((13.1392, 7.0292, 2.54458), rel=1e-4)  # Mitsuba 3.9.1
    assert material(scene, "c").constants["k"] == pytest.approx((13.1392, 7.0292, 2.54458), rel=1e-4)
    assert p["lamp.emission"] == pytest.approx([15.381, 6.6864, 2.18035], rel=1e-4)  # Mitsuba 3.9.1
    # out of gamut: bounded clamps to [0, 1], unbounded only below 0 (Mitsuba 3.9.1 spectrum_list_to_srgb)
    w, v = [400, 500, 600, 700], [0.1, 0.9, 1.5, 2]
    assert spectrum_to_srgb(w, v, bounded=True, d65=True) == pytest.approx([1, 1, 0.440512], rel=1e-4)
    assert spectrum_to_srgb(w, v, bounded=False, d65=True) == pytest.approx([1.71941, 1.16684, 0.440512], rel=1e-4)
    assert spectrum_to_srgb([400, 500], [1, 2], bounded=False, d65=False) == pytest.approx([0, 0.0519205, 1.51775], rel=1e-4)


@pytest.mark.parametrize("value, words", [
    ("400:0.1, 500", "malformed spectrum: expected wavelength:value pairs, got '500'"),
    ("400:0.1, 500:x", "malformed spectrum: could not parse the wavelength:value pair '500:x'"),
    ("500:0.1, 400:0.2", "malformed spectrum: wavelengths must not decrease"),
])  # fmt: skip
def test_malformed_spectra(tmp_path, value, words):
    path = write(tmp_path / "s.xml", f'<shape type="rectangle"><bsdf type="diffuse">\n<spectrum name="reflectance" value="{value}"/></bsdf></shape>')
    message = error_of(path)
    assert message.startswith(f"{path}:{line_of(path, 'spectrum')}: <spectrum name=\"reflectance\">: {words}"), message
    (tmp_path / "bad.spd").write_text("400 0.5\n500 0.5 0.2\n")
    path = write(tmp_path / "f.xml", '<shape type="rectangle"><bsdf type="diffuse">\n<spectrum name="reflectance" filename="bad.spd"/></bsdf></shape>')
    assert "malformed spectrum: line 2 of" in error_of(path) and error_of(path).startswith(f"{path}:{line_of(path, 'spectrum')}:")


# ---------------------------------------------------------------- objects declared at the top level


def test_area_emitter_declared_outside_its_shape(tmp_path):
    path = write(tmp_path / "s.xml", """
    <emitter type="area" id="light"><rgb name="radiance" value="2, 3, 4"/></emitter>
    <bsdf type="diffuse" id="white"/>
    <shape type="rectangle" id="panel"><ref id="light"/><ref id="white"/></shape>
    <shape type="cube"><ref name="bsdf" id="white"/></shape>""")
    scene = load_mitsuba_xml(path)
    assert scene.emitters == ("panel",) and scene.params["panel.emission"].tolist() == [2, 3, 4]
    assert scene.materials == ("white",)
    lonely = write(tmp_path / "l.xml", '<shape type="rectangle"/>\n<emitter type="area" id="light"/>')
    assert "declared outside a shape must be attached to one" in error_of(lonely)


# ---------------------------------------------------------------- every problem at once


def test_every_problem_is_listed_in_one_error(tmp_path):
    path = write(tmp_path / "s.xml", """
    <shape type="rectangle"><bsdf type="diffuse">
        <float name="roughness" value="1"/>
        <float name="sheen" value="1"/></bsdf></shape>
    <shape type="hair"/>
    <shape type="rectangle"><medium type="homogeneous" name="interior"/></shape>
    <emitter type="sunsky"/>
    <integrator type="prb"/>
    <shape type="rectangle"><bsdf type="polarizer"/></shape>
    <shape type="rectangle"><string name="filename" value="{long}"/></shape>""".replace("{long}", "x" * 300))
    message = error_of(path)
    assert message.startswith(f"{path}: 8 problems stop this scene from loading: (1) s.xml:{line_of(path, 'roughness')}: "), message
    for i, words in enumerate(["'roughness'", "'sheen'", "'hair'", "<medium> is not supported", "'sunsky'"], 1):
        assert f"({i}) " in message and words in message.split(f"({i}) ")[1], (i, message)
    assert message.endswith("... and 3 more") and "prb" not in message
    assert "x" * 60 not in message  # long values abbreviated


# ---------------------------------------------------------------- shapes, integrators, properties


def test_serialized_meshes(tmp_path):
    from invrender.scene.formats.mitsuba.serialized import write_serialized

    tri = {"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]], "uvs": [[0, 0], [1, 0], [0, 1]], "name": "tri"}
    quad = {"vertices": [[0, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1]], "faces": [[0, 1, 2], [0, 2, 3]], "normals": [[0, 0, 1]] * 4}
    for version in (3, 4):
        (tmp_path / f"m{version}.serialized").write_bytes(write_serialized([tri, quad], version=version))
    path = write(tmp_path / "s.xml", """
    <shape type="serialized"><string name="filename" value="m4.serialized"/></shape>
    <shape type="serialized"><string name="filename" value="m3.serialized"/><integer name="shape_index" value="1"/>
        <transform name="to_world"><translate z="1"/></transform></shape>""")
    scene = load_mitsuba_xml(path)
    corners = scene.triangles.corners()
    assert corners.shape[0] == 3 and corners[0].tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    assert corners[1:, :, 2].flatten().tolist() == [2] * 6 and corners[2].tolist() == [[0, 0, 2], [2, 2, 2], [0, 2, 2]]
    assert scene.triangles.uv[0].tolist() == [[0, 1], [1, 1], [0, 0]]  # stored unflipped, as Mitsuba (invrender's v = 1 - v)
    # corrupt files: one line naming the file and line
    data = (tmp_path / "m4.serialized").read_bytes()
    for name, bad, words in (("magic", b"\0\0" + data[2:], "not a serialized mesh file (format identifier 0x0000"),
                             ("zlib", data[:4] + b"garbage" + data[11:], "corrupt compressed data"),
                             ("short", data[:30], "truncated mesh data")):  # fmt: skip
        (tmp_path / f"{name}.serialized").write_bytes(bad)
        p = write(tmp_path / f"{name}.xml", f'<shape type="serialized">\n<string name="filename" value="{name}.serialized"/></shape>')
        assert error_of(p).startswith(f"{p}:{line_of(p, 'filename')}: <shape type=\"serialized\">: corrupt serialized file "), error_of(p)
        assert words in error_of(p), error_of(p)
    p = write(tmp_path / "index.xml", '<shape type="serialized"><string name="filename" value="m4.serialized"/>\n<integer name="shape_index" value="2"/></shape>')
    assert error_of(p).startswith(f"{p}:{line_of(p, 'shape_index')}:") and "shape_index 2 is out of range: the file has 2 meshes" in error_of(p)


def test_disk_and_cylinder_follow_mitsubas_parametrization(tmp_path):
    """Mitsuba 3.9.1 scalar_rgb, ray hits: a cylinder radius 0.5 from 0 0 0 to 0 0 2 at
    (0.4899, 0.1, 0.5) has uv (0.0320471, 0.25) and normal (0.9798, 0.2, 0); a disk at
    (-0.2, -0.3, 0) has uv (0.360555, 0.656416): uv = (phi / 2 pi, z / length), (r, phi / 2 pi)."""
    path = write(tmp_path / "s.xml", """
    <shape type="cylinder"><float name="radius" value="0.5"/><point name="p1" x="0" y="0" z="2"/></shape>
    <shape type="disk"/>""")
    scene = load_mitsuba_xml(path)
    tris = scene.triangles
    corners, uv = tris.corners().numpy(), tris.uv.numpy()
    n_cyl = 2 * 256
    cyl, disk = corners[:n_cyl].reshape(-1, 3), corners[n_cyl:].reshape(-1, 3)
    assert np.allclose(np.linalg.norm(cyl[:, :2], axis=1), 0.5) and set(np.round(cyl[:, 2], 9)) == {0.0, 2.0}
    u = uv[:n_cyl].reshape(-1, 2)
    phi = np.mod(np.arctan2(cyl[:, 1], cyl[:, 0]), 2 * np.pi) / (2 * np.pi)
    assert np.allclose(np.where(np.isclose(u[:, 0], 1.0), 0.0, u[:, 0]), np.where(np.isclose(phi, 1.0), 0.0, phi), atol=1e-6)
    assert np.allclose(1.0 - u[:, 1], cyl[:, 2] / 2)
    geometric = np.cross(corners[:n_cyl, 1] - corners[:n_cyl, 0], corners[:n_cyl, 2] - corners[:n_cyl, 0])
    assert np.all(np.einsum("ij,ij->i", geometric, corners[:n_cyl].mean(1) * [1, 1, 0]) > 0)  # facing outwards
    r = np.linalg.norm(disk[:, :2], axis=1)
    duv = uv[n_cyl:].reshape(-1, 2)
    assert np.allclose(duv[:, 0], r) and np.allclose(disk[:, 2], 0)
    rim = r > 0.5
    wrap = np.mod(1.0 - duv[rim, 1] - np.arctan2(disk[rim, 1], disk[rim, 0]) / (2 * np.pi) + 0.5, 1.0) - 0.5
    assert np.allclose(wrap, 0.0, atol=1e-6)
    assert np.mod(np.arctan2(-0.3, -0.2), 2 * np.pi) / (2 * np.pi) == pytest.approx(0.656416, abs=1e-6)  # Mitsuba's v there


def test_moment_integrator_and_accepted_defaults(tmp_path):
    path = write(tmp_path / "s.xml", """
    <integrator type="moment"><integrator type="path"><integer name="max_depth" value="5"/></integrator></integrator>
    <shape type="rectangle"><bsdf type="dielectric"><float name="specular_reflectance" value="1"/></bsdf>
        <emitter type="area"><float name="sampling_weight" value="1"/></emitter></shape>
    <texture type="bitmap" id="t"><string name="filename" value="t.png"/><string name="wrap_mode" value="Repeat"/></texture>""")
    from PIL import Image

    Image.fromarray(np.zeros((2, 2, 3), dtype=np.uint8)).save(tmp_path / "t.png")
    with pytest.warns(UserWarning, match="the moment images .* are not produced"):
        scene = load_mitsuba_xml(path)
    assert scene.defaults["integrator"] == "path" and scene.defaults["max_depth"] == 5
    bad = write(tmp_path / "b.xml", '<shape type="rectangle"><bsdf type="dielectric">\n<float name="specular_reflectance" value="0.5"/></bsdf>'
                '<emitter type="area"><float name="sampling_weight" value="2"/></emitter></shape>')
    message = error_of(bad)
    assert "2 problems" in message and "'specular_reflectance' other than 1 (Mitsuba's default) is not supported by invrender's dielectric" in message
    assert "'sampling_weight' other than 1 (Mitsuba's default) is not supported by invrender's area" in message


def test_a_scene_using_the_language_renders_as_mitsuba(tmp_path):
    """<path>, <include> with a <default> spectrum, a serialized floor (shape_index 1), a
    cylinder, a disk lamp whose area emitter is declared in the included file, wavelength-list
    reflectance and radiance: channel means within 2% of Mitsuba 3.9.1's (scalar_rgb, the same
    files, 4096 spp: 0.282146, 0.166536, 0.098576)."""
    import invrender as ir
    from invrender.scene.formats.mitsuba.serialized import write_serialized

    (tmp_path / "meshes").mkdir()
    floor = {"vertices": [[-3, -1, -3], [-3, -1, 3], [3, -1, 3], [3, -1, -3]], "faces": [[0, 1, 2], [0, 2, 3]]}
    (tmp_path / "meshes" / "floor.serialized").write_bytes(write_serialized([{"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]]}, floor]))
    write(tmp_path / "materials.xml", """
    <default name="warm" value="400:0.2, 500:0.4, 600:0.7, 700:0.8"/>
    <bsdf type="diffuse" id="floor_bsdf"><spectrum name="reflectance" value="$warm"/></bsdf>
    <bsdf type="diffuse" id="blue"><rgb name="reflectance" value="0.2, 0.3, 0.7"/></bsdf>
    <emitter type="area" id="lamp_light"><spectrum name="radiance" value="400:4, 500:6, 600:8, 700:8"/></emitter>""", sensor=False)
    path = write(tmp_path / "scene.xml", """
    <path value="meshes"/>
    <include filename="materials.xml"/>
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0.3, 5" target="0, -0.2, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="24"/><rfilter type="box"/></film>
    </sensor>
    <shape type="serialized"><string name="filename" value="floor.serialized"/><integer name="shape_index" value="1"/><ref id="floor_bsdf"/></shape>
    <shape type="cylinder"><float name="radius" value="0.4"/><point name="p0" x="-0.8" y="-1" z="0"/><point name="p1" x="-0.8" y="0.6" z="0"/><ref id="blue"/></shape>
    <shape type="disk" id="lamp">
        <transform name="to_world"><scale value="0.6"/><rotate x="1" angle="90"/><translate x="0.5" y="1.2" z="0.5"/></transform>
        <ref id="lamp_light"/>
    </shape>""", sensor=False)
    scene = ir.load_scene(path)
    image = ir.render(scene, spp=64, max_depth=3, seed=0, progress=False)
    means = np.asarray(image).reshape(-1, 3).mean(0)
    assert means == pytest.approx([0.282146, 0.166536, 0.098576], rel=0.02)


def test_sampler_and_film_declared_at_the_top_level(tmp_path):
    path = tmp_path / "s.xml"
    path.write_text("""<scene version="2.1.0">
    <sampler type="ldsampler" id="my_sampler"><integer name="sample_count" value="9"/></sampler>
    <film type="hdrfilm" id="film"><integer name="width" value="10"/><integer name="height" value="4"/></film>
    <sensor type="perspective"><float name="fov" value="40"/><ref id="my_sampler"/><ref id="film"/></sensor>
    <shape type="rectangle"/>
</scene>""")
    scene = load_mitsuba_xml(path)
    assert scene.defaults["spp"] == 9 and scene.resolution == (10, 4)
