"""What the census of public Mitsuba files asked the XML reader for: a perspective sensor without
``fov`` (Mitsuba's ``focal_length``, 50 mm by default, on a 36 x 24 mm film), Mitsuba's
``max_depth`` -1 when an integrator states none, ``volpath``/``volpathmis`` read as ``path``, and
the ``thindielectric`` BSDF; each checked against numbers a broken reader would get wrong."""

from __future__ import annotations

import math

import pytest

import invrender as ir
from invrender.errors import SceneError

DIAGONAL = math.hypot(36.0, 24.0)  # mm, the film Mitsuba's focal_length refers to


def xml(tmp_path, sensor="", integrator="", body='<shape type="rectangle"><bsdf type="diffuse"/></shape>', film=(64, 48), name="s.xml"):
    path = tmp_path / name
    path.write_text(
        '<scene version="3.0.0">\n'
        f"{integrator}\n"
        f'<sensor type="perspective">\n{sensor}\n<transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>\n'
        f'<film type="hdrfilm"><integer name="width" value="{film[0]}"/><integer name="height" value="{film[1]}"/></film>\n</sensor>\n'
        f"{body}\n</scene>\n"
    )
    return path


def x_fov(scene) -> float:
    tx, _ = scene.camera.tan_half_fov(scene.width, scene.height)
    return math.degrees(2 * math.atan(tx))


def expected_x_fov(focal: float, width: int, height: int) -> float:
    """Mitsuba's: the diagonal field of view of a 36 x 24 mm film behind a ``focal`` mm lens, spread
    over the film's diagonal; its horizontal share for a width x height film."""
    diagonal = DIAGONAL / focal  # 2 tan(half the diagonal fov)
    width_part = diagonal / math.sqrt(1 + (height / width) ** 2)
    return math.degrees(2 * math.atan(width_part / 2))


def test_a_sensor_without_fov_has_mitsubas_50mm_lens(tmp_path):
    scene = ir.load_scene(xml(tmp_path))
    # 50 mm on 36 x 24: diagonal fov 46.79 degrees; on a 4:3 film the x-fov is 38.18 (Mitsuba 3.9.1's x_fov: 38.184841)
    assert x_fov(scene) == pytest.approx(expected_x_fov(50, 64, 48), abs=1e-9)
    assert x_fov(scene) == pytest.approx(38.184841, abs=1e-5)
    # the diagonal really is the lens's: tan(diag/2)^2 = tan(x/2)^2 + tan(y/2)^2
    tx, ty = scene.camera.tan_half_fov(64, 48)
    assert math.hypot(tx, ty) == pytest.approx(DIAGONAL / 100, rel=1e-12)


def test_focal_length_and_the_aspect_it_is_seen_at(tmp_path):
    path = xml(tmp_path, '<string name="focal_length" value="35mm"/>\n<string name="fov_axis" value="y"/>')
    scene = ir.load_scene(path)
    assert x_fov(scene) == pytest.approx(expected_x_fov(35, 64, 48), abs=1e-9)  # fov_axis is moot beside a lens
    square = ir.load_scene(path, resolution=(32, 32))  # loaded at another aspect: the lens's diagonal spans that film
    assert x_fov(square) == pytest.approx(expected_x_fov(35, 32, 32), abs=1e-9)
    assert x_fov(square) == pytest.approx(47.216316, abs=1e-5)  # Mitsuba 3.9.1's x_fov for 35mm on a square film
    bare = ir.load_scene(xml(tmp_path, '<string name="focal_length" value="24"/>', name="b.xml"))  # "mm" is optional, as in Mitsuba
    assert x_fov(bare) == pytest.approx(expected_x_fov(24, 64, 48), abs=1e-9)


@pytest.mark.parametrize(
    "sensor, words",
    [
        ('<string name="focal_length" value="-5mm"/>', "'focal_length' '-5mm' must be a positive length in millimetres"),
        ('<string name="focal_length" value="50 mm x"/>', "must be a positive length in millimetres"),
        ('<float name="focal_length" value="50"/>', "'focal_length' must be a <string> such as \"50mm\""),
        ('<float name="fov" value="30"/><string name="focal_length" value="50mm"/>', "give either 'fov' or 'focal_length', not both"),
    ],
)
def test_bad_focal_lengths_are_one_line_errors(tmp_path, sensor, words):
    path = xml(tmp_path, sensor)
    with pytest.raises(SceneError) as info:
        ir.load_scene(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}:") and words in message, message


@pytest.mark.parametrize(
    "integrator, defaults",
    [
        ('<integrator type="path"/>', {"integrator": "path", "max_depth": -1}),  # Mitsuba's default, not invrender's 8
        ('<integrator type="path"><integer name="rr_depth" value="3"/></integrator>', {"integrator": "path", "max_depth": -1, "rr_depth": 3}),
        ('<integrator type="path"><integer name="max_depth" value="5"/></integrator>', {"integrator": "path", "max_depth": 5}),
        ('<integrator type="direct"/>', {"integrator": "path", "max_depth": 2}),  # direct fixes its own
        ('<integrator type="moment"><integrator type="path"/></integrator>', {"integrator": "path", "max_depth": -1}),
        ("", {}),  # a file that states nothing: invrender's defaults
    ],
)
def test_max_depth_is_mitsubas_when_the_integrator_states_none(tmp_path, integrator, defaults):
    scene = ir.load_scene(xml(tmp_path, '<float name="fov" value="40"/>', integrator))
    assert scene.defaults == defaults


def test_unbounded_depth_renders_deep_glass_paths(tmp_path):
    """A glass sphere under a uniform sky: a finite max_depth cuts the paths that bounce inside it; the file's
    path integrator with no max_depth is Mitsuba's unbounded one, and renders brighter."""
    body = (
        '<shape type="sphere"><float name="radius" value="0.8"/><bsdf type="dielectric"/></shape>\n'
        '<emitter type="constant"><rgb name="radiance" value="1"/></emitter>'
    )
    scene = ir.load_scene(xml(tmp_path, '<float name="fov" value="10"/>', '<integrator type="path"/>', body, film=(8, 8)))
    assert scene.defaults["max_depth"] == -1
    deep = ir.render(scene, spp=256, seed=0, progress=False)
    cut = ir.render(scene, spp=256, seed=0, max_depth=2, progress=False)  # reflections only: no path through the glass
    # through a sphere of glass from a uniform surround: radiance 1 seen everywhere when nothing is cut
    assert float(deep.mean()) == pytest.approx(1.0, abs=0.03)
    assert float(cut.mean()) < 0.2


@pytest.mark.parametrize("kind", ["volpath", "volpathmis"])
def test_volumetric_path_tracers_without_media_are_path(tmp_path, kind):
    path = xml(tmp_path, '<float name="fov" value="40"/>', f'<integrator type="{kind}"><integer name="max_depth" value="6"/><boolean name="hide_emitters" value="true"/></integrator>')
    with pytest.warns(UserWarning, match=f'{kind}">: read as <integrator type="path"> \\(the scene has no media'):
        scene = ir.load_scene(path)
    assert scene.defaults == {"integrator": "path", "max_depth": 6, "hide_emitters": True}
    with pytest.warns(UserWarning):
        assert ir.load_scene(xml(tmp_path, '<float name="fov" value="40"/>', f'<integrator type="{kind}"/>', name="b.xml")).defaults["max_depth"] == -1
    with pytest.raises(SceneError, match="unsupported property 'sigma_t'"), pytest.warns(UserWarning):
        ir.load_scene(xml(tmp_path, '<float name="fov" value="40"/>', f'<integrator type="{kind}"><float name="sigma_t" value="1"/></integrator>', name="c.xml"))


def pane_scene(tmp_path, ior="1.5", extra=""):
    """A thin pane filling the view (fov 2 degrees: near normal incidence), a red emitter behind the
    camera facing the pane and a blue one behind the pane facing the camera."""
    body = (
        f'<shape type="rectangle"><transform name="to_world"><scale value="20"/></transform>'
        f'<bsdf type="thindielectric"><float name="int_ior" value="{ior}"/>{extra}</bsdf></shape>\n'
        '<shape type="rectangle"><transform name="to_world"><scale value="50"/><rotate x="1" angle="180"/><translate z="6"/></transform>'
        '<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf><emitter type="area"><rgb name="radiance" value="1, 0, 0"/></emitter></shape>\n'
        '<shape type="rectangle"><transform name="to_world"><scale value="50"/><translate z="-3"/></transform>'
        '<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf><emitter type="area"><rgb name="radiance" value="0, 0, 1"/></emitter></shape>'
    )
    return xml(tmp_path, '<float name="fov" value="2"/>', "", body, film=(4, 4))


@pytest.mark.parametrize("ior", [1.5, 1.333])
def test_thindielectric_reflects_2F_over_1_plus_F_and_transmits_straight_through(tmp_path, ior):
    scene = ir.load_scene(pane_scene(tmp_path, str(ior)))
    assert scene.material_spec(scene.materials.index("material_1")).type == "thindielectric"
    F = ((ior - 1) / (ior + 1)) ** 2
    R = 2 * F / (1 + F)  # 0.0769 for 1.5 where one interface reflects 0.04
    img = ir.render(scene, "whitted", spp=1, max_depth=3, progress=False).double()
    mean = img.mean((0, 1))
    # red: the emitter behind the camera, reflected; blue: the one behind the pane, seen straight through
    assert float(mean[0]) == pytest.approx(R, rel=2e-3)
    assert float(mean[2]) == pytest.approx(1 - R, rel=2e-4)
    assert float(mean[1]) == 0.0
    path = ir.render(scene, "path", spp=256, seed=0, max_depth=3, progress=False).double().mean((0, 1))
    se = math.sqrt(R * (1 - R) / (16 * 256))
    assert abs(float(path[0]) - R) < 4 * se and abs(float(path[2]) - (1 - R)) < 4 * se


def test_thindielectric_takes_named_media_and_refuses_what_it_lacks(tmp_path):
    scene = ir.load_scene(pane_scene(tmp_path, "1.5", '<string name="ext_ior" value="water"/>'))
    assert scene.material_spec(scene.materials.index("material_1")).constants["ior"] == pytest.approx(1.5 / 1.3330)
    with pytest.raises(SceneError, match="'specular_transmittance' other than 1 \\(Mitsuba's default\\) is not supported by invrender's thindielectric"):
        ir.load_scene(pane_scene(tmp_path, "1.5", '<rgb name="specular_transmittance" value="0.5"/>'))
    with pytest.raises(SceneError, match="'int_ior' must be positive"):
        ir.load_scene(pane_scene(tmp_path, "-1"))


def ortho_scene(tmp_path, to_world, film=(32, 32)):
    body = ('<shape type="rectangle"><transform name="to_world"><scale value="0.5"/></transform>'
            '<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>')
    path = tmp_path / "o.xml"
    path.write_text(
        '<scene version="3.0.0"><sensor type="orthographic"><float name="near_clip" value="0.1"/>'
        f'<transform name="to_world">{to_world}</transform>'
        f'<film type="hdrfilm"><integer name="width" value="{film[0]}"/><integer name="height" value="{film[1]}"/></film></sensor>\n{body}\n</scene>\n'
    )
    return path


@pytest.mark.parametrize("distance", [2.0, 10.0])
def test_orthographic_sees_the_same_window_at_any_distance(tmp_path, distance):
    """A 1 x 1 emitter in a window of camera space [-1, 1]^2 (a square film): a quarter of the
    pixels, exactly, whatever the distance (a perspective camera would see it shrink)."""
    look = f'<lookat origin="0, 0, {distance}" target="0, 0, 0" up="0, 1, 0"/>'
    scene = ir.load_scene(ortho_scene(tmp_path, look))
    assert type(scene.camera).__name__ == "OrthographicCamera" and scene.camera.extent == (1.0, 1.0)
    assert scene.film.filter.type_name == "gaussian"  # hdrfilm's default; the box shows the window's pixel edges exactly
    img = ir.render(scene, spp=4, seed=0, max_depth=1, progress=False, filter="box")
    assert float(img.double().mean()) == pytest.approx(0.25, abs=1e-6)
    # the window scales with the to_world's x and y scales, and with the film's aspect along y (Mitsuba's [-1/aspect, 1/aspect])
    wide = ir.load_scene(ortho_scene(tmp_path, f'<scale x="2" y="0.5"/>{look}', film=(32, 16)))
    assert wide.camera.extent == (2.0, 0.5)  # window 4 wide, 0.5 * 16/32 * 2 = 0.5 high: the emitter fills 1/4 of the width, all the height
    img = ir.render(wide, spp=4, seed=0, max_depth=1, progress=False, filter="box")
    assert float(img.double().mean()) == pytest.approx(0.25, abs=1e-6)
    assert float(img[:, :12].max()) == 0.0 and float(img[:, 12:20].min()) == 1.0


def test_bad_orthographic_sensors(tmp_path):
    for to_world, words in [
        ('<matrix value="1 0.5 0 0  0 1 0 0  0 0 1 0  0 0 0 1"/>', "an orthographic sensor's to_world must be a scale, a rotation and a translation: it shears"),
        ('<scale x="-1"/>', "mirrored or singular"),
    ]:
        path = ortho_scene(tmp_path, to_world)
        with pytest.raises(SceneError) as info:
            ir.load_scene(path)
        assert str(info.value).startswith(f"{path}:") and words in str(info.value) and "\n" not in str(info.value)
    path = ortho_scene(tmp_path, '<lookat origin="0, 0, 2" target="0, 0, 0"/>').read_text().replace('<float name="near_clip" value="0.1"/>', '<float name="fov" value="30"/>')
    (tmp_path / "f.xml").write_text(path)
    with pytest.raises(SceneError, match="unsupported property 'fov'"):
        ir.load_scene(tmp_path / "f.xml")


@pytest.mark.parametrize(
    "bsdf, flip, expected",
    [
        ('<bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>', False, 0.5),  # its front
        ('<bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>', True, 0.0),  # its back: black, as Mitsuba's
        ('<bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></bsdf>', True, 0.5),
        ('<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.5"/></bsdf>', True, 0.0),
    ],
    ids=["front", "back", "twosided back", "plastic back"],
)
def test_bsdfs_without_twosided_are_black_from_behind(tmp_path, bsdf, flip, expected):
    """A plane filling the view under a uniform sky of radiance 1: a diffuse albedo 0.5 reflects
    0.5 (direct light only) from its front, and from its back only inside ``twosided``."""
    body = (
        f'<shape type="rectangle"><transform name="to_world"><scale value="5"/></transform><boolean name="flip_normals" value="{str(flip).lower()}"/>{bsdf}</shape>\n'
        '<emitter type="constant"><rgb name="radiance" value="1"/></emitter>'
    )
    scene = ir.load_scene(xml(tmp_path, '<float name="fov" value="30"/>', "", body, film=(8, 8)))
    spec = scene.material_spec(0)
    assert spec.one_sided == ("twosided" not in bsdf)
    mean = ir.render(scene, "path", spp=64, seed=1, max_depth=2, progress=False).double().mean()
    if expected == 0.0:
        assert float(mean) == 0.0
    elif "plastic" not in bsdf:
        assert float(mean) == pytest.approx(expected, rel=0.02)


def test_transmitting_bsdfs_stay_two_sided(tmp_path):
    scene = ir.load_scene(pane_scene(tmp_path))
    assert not scene.material_spec(scene.materials.index("material_1")).one_sided
