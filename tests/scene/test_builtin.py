"""Built-in scenes: the Cornell box as Mitsuba 3 defines it, the furnace, parameters."""

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError, SceneError


def test_cornell_box_params_and_counts():
    scene = ir.load_scene("cornell_box", resolution=(64, 48))
    assert scene.resolution == (64, 48)
    assert set(scene.params) == {"white.reflectance", "red.reflectance", "green.reflectance", "light.emission"}
    assert torch.allclose(scene.params["light.emission"], torch.tensor([18.387, 13.9873, 6.75357]))
    assert scene.triangles.count == 5 * 2 + 2 * 12 + 2
    light = scene.triangles.emitter >= 0
    assert torch.isclose(scene.triangles.area[light].sum(), torch.tensor(0.46 * 0.38), rtol=1e-5)
    assert torch.allclose(scene.triangles.normal[light], torch.tensor([0.0, -1.0, 0.0]).expand(2, 3), atol=1e-6)


def test_cornell_box_red_left_green_right_top_row_is_ceiling():
    scene = ir.load_scene("cornell_box", resolution=(32, 32))
    img = ir.render(scene, spp=16, max_depth=3, progress=False)
    left, right = img[8:24, 1], img[8:24, 30]
    assert (left[:, 0] > 2 * left[:, 1]).all()  # red wall on the left
    assert (right[:, 1] > 2 * right[:, 0]).all()  # green wall on the right
    terms = ir.render(scene, spp=4, max_depth=1, progress=False)
    rows = (terms.sum(-1) > 0).nonzero()[:, 0]
    assert rows.max() < 8  # the light is seen in the top rows: row 0 is the top


def test_params_are_leaves_read_at_render_time():
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    before = ir.render(scene, spp=4, progress=False)
    with torch.no_grad():
        scene.params["light.emission"].mul_(2.0)
    after = ir.render(scene, spp=4, progress=False)
    assert torch.allclose(after, 2 * before, rtol=1e-5, atol=1e-6)
    assert all(p.is_leaf for p in scene.params.values())


def test_furnace_arguments_and_validation():
    scene = ir.load_scene("furnace", rho=0.25, eps=[1.0, 2.0, 3.0], resolution=(4, 4))
    assert torch.allclose(scene.params["wall.reflectance"], torch.tensor([0.25] * 3))
    assert torch.allclose(scene.params["glow.emission"], torch.tensor([1.0, 2.0, 3.0]))
    with pytest.raises(ParameterError, match=r"rho must lie in \[0, 1\]"):
        ir.load_scene("furnace", rho=1.5)
    with pytest.raises(ParameterError, match="eps must be >= 0"):
        ir.load_scene("furnace", eps=-1.0)
    with pytest.raises(SceneError, match=r"^unknown scene 'cornel_box' \(did you mean 'cornell_box'\?\): not a built-in"):
        ir.load_scene("cornel_box")
    with pytest.raises(SceneError, match="resolution"):
        ir.load_scene("cornell_box", resolution=(0, 4))


def test_degenerate_triangles_dropped_with_warning():
    from invrender.scene import Camera, Mesh, build_scene

    v = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], dtype=torch.float64).numpy()
    f = torch.tensor([[0, 1, 2], [0, 1, 3]]).numpy()  # the second is a line
    with pytest.warns(UserWarning, match="degenerate"):
        scene = build_scene([Mesh(v, f, None, "m")], {"m": [0.5] * 3}, {}, Camera(), (4, 4))
    assert scene.triangles.count == 1
    with pytest.raises(SceneError, match="index out of range"):
        build_scene([Mesh(v, f + 3, None, "m")], {"m": [0.5] * 3}, {}, Camera(), (4, 4))


def test_sky_spheres_loads_renders_and_shows_its_map():
    """The envmap scene: its parameters, the sun is the map's brightest texel, and the background
    pixels are the map's radiance along their directions."""
    from invrender.plugins.emitters.envmap import Envmap, quaternion_of
    from invrender.scene.builtin import map_directions, sun_direction

    scene = ir.load_scene("sky_spheres", resolution=(32, 32), map_size=(8, 16), subdivisions=2)
    assert set(scene.params) == {"floor.reflectance", "diffuse.reflectance", "glossy.specular_reflectance", "glossy.roughness", "sky.emission", "diffuse.normals", "glossy.normals"}
    sky = scene.params["sky.emission"]
    assert sky.shape == (8, 16, 3) and bool((sky > 0).all())
    luminance = sky @ torch.tensor([0.212671, 0.715160, 0.072169])
    nearest = (map_directions(8, 16) @ sun_direction()).argmax()
    assert int(luminance.argmax()) == int(nearest) and float(luminance.max()) > 5 * float(luminance.median())
    torch.testing.assert_close(ir.load_scene("sky_spheres", map_size=(8, 16)).params["sky.emission"], sky)  # deterministic

    img = ir.render(scene, spp=16, max_depth=4, seed=1, progress=False)
    assert img.shape == (32, 32, 3) and bool(torch.isfinite(img).all()) and float(img.mean()) > 0.05
    # the top two rows see only the sky: the map's bilinear radiance at each pixel centre
    yx = torch.stack(torch.meshgrid(torch.arange(2), torch.arange(32), indexing="ij"), -1).reshape(-1, 2).float() + 0.5
    _, d = scene.camera.generate_rays(yx.flip(-1), 32, 32)
    L = Envmap([0], [{"emission": sky}], [{"scale": 1.0, **quaternion_of(torch.eye(3).numpy(), "test")}], scene.triangles).escaped(d)
    torch.testing.assert_close(img[:2].reshape(-1, 3), L, rtol=0.02, atol=0.0)
    hidden = ir.render(scene, {"type": "path", "hide_emitters": True}, spp=4, max_depth=4, progress=False)
    assert float(hidden[:2].abs().max()) == 0.0  # hide_emitters: a black background
    with pytest.raises(SceneError, match="map_size"):
        ir.load_scene("sky_spheres", map_size=(2, 2))


def test_cornell_materials_params_and_its_materials_show():
    """The fitting scene: the rough metal block and the plastic sphere with their parameters; the
    block's pixels follow its roughness, the sphere's its base, and nothing else moves."""
    scene = ir.load_scene("cornell_materials", resolution=(24, 24), subdivisions=1)
    assert set(scene.params) == {
        "white.reflectance", "red.reflectance", "green.reflectance", "light.emission",
        "metal.specular_reflectance", "metal.roughness", "plastic.reflectance", "plastic.specular_reflectance", "plastic.normals",
    }  # fmt: skip
    torch.testing.assert_close(scene.params["metal.roughness"], torch.tensor([0.3] * 3))
    assert scene.triangles.count == 5 * 2 + 12 + 20 * 4 + 2
    assert scene.material_spec(scene.materials.index("metal")).type == "glossy"
    assert scene.material_spec(scene.materials.index("plastic")).type == "plastic"
    kw = dict(spp=8, max_depth=4, seed=1, progress=False)
    base = ir.render(scene, **kw)
    assert bool(torch.isfinite(base).all()) and 0.05 < float(base.mean()) < 1.0
    metal = (base - ir.render(scene.with_params({"metal.roughness": 0.05}), **kw)).abs().sum(-1)
    plastic = (base - ir.render(scene.with_params({"plastic.reflectance": [0.6, 0.6, 0.6]}), **kw)).abs().sum(-1)
    # the tall block is left of centre, the sphere right of centre near the bottom
    assert float(metal[:, :12].sum()) > 3 * float(metal[:, 12:].sum()) > 0
    assert float(plastic[12:, 12:].sum()) > 3 * float(plastic[:12, :12].sum()) > 0


@pytest.mark.parametrize(
    "name, options, message",
    [
        ("sky_spheres", {"map_size": (4,)}, "sky_spheres: 'map_size' must be two integers (rows, columns), got (4,)"),
        ("sky_spheres", {"map_size": 4}, "sky_spheres: 'map_size' must be two integers (rows, columns), got 4"),
        ("sky_spheres", {"map_size": (3.5, 8)}, "sky_spheres: 'map_size' must be two integers (rows, columns), got (3.5, 8)"),
        ("sky_spheres", {"map_size": ("4", 8)}, "sky_spheres: 'map_size' must be two integers (rows, columns), got ('4', 8)"),
        ("sky_spheres", {"map_size": (2, 2)}, "sky_spheres: 'map_size' must be at least (3, 4), got (2, 2)"),
        ("sky_spheres", {"map_size": (100000, 100000)}, "sky_spheres: 'map_size' (100000, 100000) is 10000000000 texels, more than 16777216"),
        ("sky_spheres", {"sky": "blue"}, "sky_spheres: 'sky' must be an (h, w, 3) texture, got 'blue'"),
        ("sky_spheres", {"subdivisions": 2.5}, "sky_spheres: 'subdivisions' must be an integer in [0, 7] (an icosphere of 20 * 4^n triangles), got 2.5"),
        ("cornell_specular", {"subdivisions": True}, "cornell_specular: 'subdivisions' must be an integer in [0, 7] (an icosphere of 20 * 4^n triangles), got True"),
        ("cornell_materials", {"subdivisions": 9}, "cornell_materials: 'subdivisions' must be an integer in [0, 7] (an icosphere of 20 * 4^n triangles), got 9"),
        ("furnace", {"rho": "grey"}, "furnace: 'rho' must be a number, an RGB triple or an (h, w, 3) texture, got 'grey'"),
        ("furnace", {"eps": [1, 2]}, "furnace: 'eps' must be a number, an RGB triple or an (h, w, 3) texture, got [1, 2]"),
        ("cornell_box", {"resolutoin": (8, 8)}, "built-in scene 'cornell_box' has no option 'resolutoin' (did you mean 'resolution'?) (options: resolution)"),
        ("furnace", {"map_size": (4, 8)}, "built-in scene 'furnace' has no option 'map_size' (options: resolution, rho, eps, subdivisions)"),
    ],
)
def test_builtin_options_are_checked_before_the_scene_is_made(name, options, message):
    """Every keyword option of a built-in scene: a one-line SceneError naming the scene, the option
    and the value (a short map_size used to be a bare ValueError from unpacking)."""
    with pytest.raises(SceneError) as info:
        ir.load_scene(name, **options)
    assert str(info.value) == message
