"""A material defined outside the package loads from the scene formats through the registry: its
``type`` in TOML, its ``mitsuba_plugins`` in XML, its ``from_gltf`` for OBJ/glTF materials; error
messages list it while it is registered, and nothing knows it once it is unregistered."""

import pytest
import torch

import invrender as ir
from invrender import registry
from invrender.errors import SceneError
from invrender.plugins.bsdfs.mirror import Mirror
from invrender.scene.kinds import SPECULAR_REFLECTANCE
from invrender.scene.materials import Constant

SENSOR = '<sensor type="perspective"><float name="fov" value="40"/></sensor>'


class TintedMirror(Mirror):
    """A mirror whose reflection k_s is also scaled by a constant tint in [0, 1]."""

    type_name = "test_tinted"
    constants = {"tint": Constant(0.5, 0.0, 1.0, False, False)}
    doc = "a mirror times a tint"
    mitsuba_plugins = ("test_tinted",)

    def specular_lobes(self, sp):
        ((wi, weight),) = super().specular_lobes(sp)
        return [(wi, weight * self.constant("tint", sp)[:, None])]

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        ks = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0, texture=False)
        tint = bsdf.number("tint", cls.constants["tint"], "the tint factor")
        bsdf.finish(("specular_reflectance", "tint"))
        return {"specular_reflectance": ks, "tint": tint}

    gltf_priority = 0  # before the built-in ones

    @classmethod
    def from_gltf(cls, material) -> dict | None:
        return {"specular_reflectance": material.metal_colour, "tint": 0.75} if material.metal else None


@pytest.fixture
def tinted():
    registry.MATERIALS.register(TintedMirror)
    try:
        yield TintedMirror
    finally:
        registry.MATERIALS.unregister("test_tinted")


def toml_scene(tmp_path, table):
    path = tmp_path / "s.toml"
    path.write_text(f'[materials.t]\n{table}\n[[shapes]]\ntype = "rectangle"\nmaterial = "t"\n')
    return path


def xml_scene(tmp_path, bsdf):
    path = tmp_path / "s.xml"
    path.write_text(f'<scene version="3.0.0">{SENSOR}<shape type="rectangle">{bsdf}</shape></scene>')
    return path


def test_toml_type(tmp_path, tinted):
    scene = ir.load_scene(toml_scene(tmp_path, 'type = "test_tinted"\ntint = 0.25\nspecular_reflectance = [0.5, 0.25, 1.0]'), resolution=(4, 4))
    assert scene.material_specs[0].type == "test_tinted" and scene.material_specs[0].constants == {"tint": 0.25}
    assert torch.equal(scene.params["t.specular_reflectance"], torch.tensor([0.5, 0.25, 1.0]))
    assert torch.isfinite(ir.render(scene, spp=1, max_depth=2, progress=False)).all()


def test_xml_plugin(tmp_path, tinted):
    inner = '<bsdf type="test_tinted"><float name="tint" value="0.25"/><rgb name="specular_reflectance" value="0.5, 0.25, 1"/></bsdf>'
    for bsdf in (inner, f'<bsdf type="twosided">{inner}</bsdf>'):
        scene = ir.load_scene(xml_scene(tmp_path, bsdf), resolution=(4, 4))
        assert scene.material_specs[0].type == "test_tinted" and scene.material_specs[0].constants == {"tint": 0.25}
        assert torch.equal(scene.params["material_1.specular_reflectance"], torch.tensor([0.5, 0.25, 1.0]))
    with pytest.raises(SceneError, match=r"s.xml:1: <bsdf type=\"test_tinted\">: 'tint' \(the tint factor\) must lie in \[0, 1\], got 2"):
        ir.load_scene(xml_scene(tmp_path, '<bsdf type="test_tinted"><float name="tint" value="2"/></bsdf>'))
    with pytest.raises(SceneError, match=r"unsupported property 'alpha' \(supported: specular_reflectance, tint\)"):
        ir.load_scene(xml_scene(tmp_path, '<bsdf type="test_tinted"><float name="alpha" value="1"/></bsdf>'))
    with pytest.raises(SceneError, match=r"unsupported bsdf type 'hair' \(supported: diffuse, conductor, dielectric, roughconductor, plastic, roughplastic, roughdielectric, thindielectric, principled, principledthin, pplastic, blendbsdf, mask, test_tinted, twosided, normalmap, bumpmap\)"):
        ir.load_scene(xml_scene(tmp_path, '<bsdf type="hair"/>'))


def test_obj_mtl_through_from_gltf(tmp_path, tinted):
    (tmp_path / "m.mtl").write_text("newmtl shiny\nillum 3\nKs 0.5 0.25 1\nnewmtl matte\nKd 0.2 0.3 0.4\n")
    faces = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl shiny\nf 1 2 3\nusemtl matte\nf 2 4 3\n"
    (tmp_path / "m.obj").write_text("mtllib m.mtl\n" + faces)
    scene = ir.load_scene(tmp_path / "m.obj", resolution=(4, 4), studio=False)
    types = {name: spec.type for name, spec in zip(scene.materials, scene.material_specs)}
    assert types == {"shiny": "test_tinted", "matte": "diffuse"}
    assert scene.material_specs[scene.materials.index("shiny")].constants == {"tint": 0.75}
    assert torch.allclose(scene.params["shiny.specular_reflectance"], torch.tensor([0.5, 0.25, 1.0]))


def test_unregistered_is_unknown(tmp_path, tinted):
    registry.MATERIALS.unregister("test_tinted")
    with pytest.raises(SceneError, match="unknown material type 'test_tinted'"):
        ir.load_scene(toml_scene(tmp_path, 'type = "test_tinted"'))
    with pytest.raises(SceneError, match=r"unsupported bsdf type 'test_tinted' \(supported: diffuse, conductor, dielectric, roughconductor, plastic, roughplastic, roughdielectric, thindielectric, principled, principledthin, pplastic, blendbsdf, mask, twosided, normalmap, bumpmap\)"):
        ir.load_scene(xml_scene(tmp_path, '<bsdf type="test_tinted"/>'))


def test_aliases_are_not_inherited(tmp_path, tinted):
    """The subclass keeps conductor and the glTF mapping with Mirror: it declares its own aliases only."""
    scene = ir.load_scene(xml_scene(tmp_path, '<bsdf type="conductor"/>'))
    assert scene.material_specs[0].type == "mirror"
