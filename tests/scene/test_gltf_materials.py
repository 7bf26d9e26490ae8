"""glTF materials beyond the factors: ``metallicRoughnessTexture`` as roughness and metallic maps,
``normalTexture`` (with its ``scale``) as a ``normalmap`` perturbation, ``KHR_texture_transform``
as the texture's ``to_uv``, partial transmission as a principled material's ``spec_trans``, the
warning for material extensions that are not read, and a render of a normal-mapped plane."""

from __future__ import annotations

import base64
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

import invrender as ir
from invrender.errors import SceneError
from invrender.scene.formats.trimesh import load_mesh_file
from invrender.scene.materials import NormalPerturbation
from tests.scene.test_loaders import gltf_file, gltf_material


def save(folder: Path, name: str, texels) -> None:
    Image.fromarray(np.asarray(texels, dtype=np.uint8)).save(folder / name)


def encode(n) -> np.ndarray:
    """8-bit codes of unit normals n (..., 3): round((n + 1) / 2 * 255)."""
    n = np.asarray(n, dtype=np.float64)
    return np.round((n / np.linalg.norm(n, axis=-1, keepdims=True) + 1) / 2 * 255).astype(np.uint8)


def test_metallic_roughness_texture_gives_maps(tmp_path):
    mr = np.zeros((2, 2, 3), dtype=np.uint8)
    mr[..., 1] = [[255, 51], [102, 0]]  # G: roughness
    mr[..., 2] = [[0, 255], [255, 0]]  # B: metallic
    save(tmp_path, "mr.png", mr)
    rough_only = mr.copy()
    rough_only[..., 2] = 255  # a uniform metal
    save(tmp_path, "rough.png", rough_only)
    dull = mr.copy()
    dull[..., 2] = 0  # uniformly not a metal
    save(tmp_path, "dull.png", dull)
    materials = [
        gltf_material("mixed", metallicRoughnessTexture={"index": 0}, roughnessFactor=0.5),  # metallicFactor 1 (the default) x B
        gltf_material("brushed", metallicRoughnessTexture={"index": 1}),
        gltf_material("paint", metallicRoughnessTexture={"index": 2}, baseColorFactor=[0.2, 0.4, 0.6, 1]),
    ]
    scene = load_mesh_file(gltf_file(tmp_path / "m.gltf", materials, [0, 1, 2], images=["mr.png", "rough.png", "dull.png"]))
    types = {k: s.type for k, s in zip(scene.materials, scene.material_specs)}
    assert types == {"mixed": "principled", "brushed": "glossy", "paint": "diffuse"}
    p = scene.params
    g = torch.tensor([[255, 51], [102, 0]], dtype=torch.float32) / 255  # linear: the codes, not sRGB-decoded
    assert p["mixed.metallic"].shape == (2, 2, 3) and torch.equal(p["mixed.metallic"][..., 0], torch.tensor([[0.0, 1.0], [1.0, 0.0]]))
    assert torch.allclose(p["mixed.roughness"][..., 1], torch.clamp(0.5 * g, min=1e-4))  # perceptual, times the factor
    assert torch.allclose(p["brushed.roughness"][..., 2], torch.clamp(g * g, min=1e-4))  # a metal's GGX alpha = r^2
    assert torch.allclose(p["paint.reflectance"], torch.tensor([0.2, 0.4, 0.6]))


def test_normal_texture_with_scale_is_a_normalmap(tmp_path):
    n = np.array([[[0.6, 0.0, 0.8], [0.0, -0.6, 0.8]]])
    save(tmp_path, "n.png", encode(n))
    materials = [
        gltf_material("bumpy", metallicFactor=0.0),
        gltf_material("glass", {"KHR_materials_transmission": {"transmissionFactor": 1.0}}, metallicFactor=0.0, roughnessFactor=0.0),
    ]
    materials[0]["normalTexture"] = {"index": 0, "scale": 0.5}
    materials[1]["normalTexture"] = {"index": 0}
    scene = load_mesh_file(gltf_file(tmp_path / "n.gltf", materials, [0, 1], images=["n.png"]))
    bumpy, glass = scene.material_specs
    assert bumpy.type == "diffuse" and glass.type == "dielectric"
    p = bumpy.perturbation
    assert p.kind == "normalmap" and p.on_turned and p.flip_invalid and p.shadowing  # two-sided: the side the ray arrives from
    codes = encode(n) / 255.0
    expected = ((2 * codes - 1) * [0.5, 0.5, 1.0] + 1) / 2  # the spec's (2c - 1) (s, s, 1), re-encoded
    assert torch.allclose(p.texture, torch.tensor(expected, dtype=torch.float32), atol=1e-6)
    tilt = 2 * p.texture[0, 0] - 1
    assert float(tilt[0] / tilt[2]) == pytest.approx(0.5 * 0.6 / 0.8, abs=0.01)  # the slope halved
    assert not glass.perturbation.on_turned  # a transmitting material: the front side's frame, as Mitsuba's normalmap(dielectric)
    assert torch.allclose(glass.perturbation.texture, torch.tensor(codes, dtype=torch.float32))


def test_texture_transform_and_bad_inputs(tmp_path):
    save(tmp_path, "c.png", np.full((2, 2, 3), 188, dtype=np.uint8))
    transform = {"KHR_texture_transform": {"offset": [0, 1], "rotation": math.pi / 2, "scale": [0.5, 0.5]}}  # the extension's example
    materials = [gltf_material("tiled", baseColorTexture={"index": 0, "extensions": transform}, metallicFactor=0.0)]
    scene = load_mesh_file(gltf_file(tmp_path / "t.gltf", materials, [0], images=["c.png"]))
    sampling = scene.texture_sampling["tiled.reflectance"]
    corners = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], dtype=torch.float64)  # invrender's uv (v up)
    looked_up = sampling.transform(corners)
    # the example reads the image's lower-left quadrant (u and v up in [0, 0.5]), rotated: glTF's (0, 0) (top left) -> (0, 1)
    assert looked_up.min() > -1e-9 and looked_up.max() < 0.5 + 1e-9
    assert torch.allclose(looked_up[2], torch.tensor([0.0, 0.0], dtype=torch.float64), atol=1e-9)
    assert torch.allclose(looked_up[3], torch.tensor([0.0, 0.5], dtype=torch.float64), atol=1e-9)

    with pytest.warns(UserWarning, match="KHR_materials_clearcoat, KHR_materials_sheen not read"):
        load_mesh_file(gltf_file(tmp_path / "w.gltf", [gltf_material("coat", {"KHR_materials_sheen": {}, "KHR_materials_clearcoat": {}}, metallicFactor=0.0)], [0]))
    save(tmp_path, "grey.png", np.full((2, 2, 3), 128, dtype=np.uint8))  # no direction
    bad = [
        ({**gltf_material("x"), "normalTexture": {"index": 0}}, "grey.png", "normalTexture: the normal at texel (row 0, column 0) is of length"),
        ({**gltf_material("x"), "normalTexture": {"index": 0, "scale": "big"}}, "c.png", "normalTexture scale must be a finite number"),
        (gltf_material("x", baseColorTexture={"index": 0, "extensions": {"KHR_texture_transform": {"scale": [1]}}}, metallicFactor=0), "c.png", "KHR_texture_transform needs"),
    ]
    for material, image, words in bad:
        with pytest.raises(SceneError) as e:
            load_mesh_file(gltf_file(tmp_path / "bad.gltf", [material], [0], images=[image]))
        assert words in str(e.value) and "\n" not in str(e.value), str(e.value)


def lit_plane(path: Path, normal_texture: dict | None) -> Path:
    """A .gltf: a white diffuse plane [-1, 1]^2 at z = 0 facing +z (uv as the rectangle's), and an
    emitting quad at x = 1.5 facing -x, the camera on +z looking down."""
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float32)
    idx = np.array([0, 1, 2, 0, 2, 3], dtype=np.uint16)
    blob = pos.tobytes() + uv.tobytes() + idx.tobytes()
    plane = {"name": "plane", "pbrMetallicRoughness": {"metallicFactor": 0.0}}
    if normal_texture is not None:
        plane["normalTexture"] = normal_texture
    light = {"name": "light", "pbrMetallicRoughness": {"metallicFactor": 0.0, "baseColorFactor": [0, 0, 0, 1]}, "emissiveFactor": [1, 1, 1],
             "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}}}  # fmt: skip
    h = 0.5**0.5
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"mesh": 0},
            {"mesh": 1, "rotation": [0, -h, 0, h], "translation": [1.5, 0, 1.0]},  # -90 degrees about y: facing -x
            {"camera": 0, "translation": [0, 0, 4.0]},
        ],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.6, "aspectRatio": 1.0, "znear": 0.1}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": m}]} for m in (0, 1)],
        "materials": [plane, light],
        "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 32}, {"buffer": 0, "byteOffset": 80, "byteLength": 12}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
    }
    if normal_texture is not None:
        doc["images"], doc["textures"] = [{"uri": "n.png"}], [{"source": 0}]
    path.write_text(json.dumps(doc))
    return path


def test_normal_mapped_plane_renders_as_the_direct_normalmap(tmp_path):
    """Normals tilted towards the light (+x: the plane's +u, Mitsuba's tangent s) brighten the
    plane, tilted away darken it; the glTF render equals the render of the flat file's scene with
    the expected ``normalmap`` put on directly (same seed)."""
    towards, away = (np.sin(0.5), 0.0, np.cos(0.5)), (-np.sin(0.5), 0.0, np.cos(0.5))
    means = {}
    for name, n in (("towards", towards), ("away", away)):
        save(tmp_path, "n.png", np.broadcast_to(encode(n), (4, 4, 3)))
        scene = load_mesh_file(lit_plane(tmp_path / f"{name}.gltf", {"index": 0, "scale": 0.8}), resolution=(16, 16))
        means[name] = ir.render(scene, spp=16, seed=3)[4:12, 4:12].mean()
        if name == "towards":
            direct_texels = torch.tensor((((2 * (encode(n) / 255.0) - 1) * [0.8, 0.8, 1.0] + 1) / 2), dtype=torch.float32).expand(4, 4, 3).contiguous()
            flat = load_mesh_file(lit_plane(tmp_path / "flat.gltf", None), resolution=(16, 16))
            direct = NormalPerturbation("normalmap", direct_texels, on_turned=True)
            specs = tuple(dataclasses.replace(s, perturbation=direct) if m == "plane" else s for m, s in zip(flat.materials, flat.material_specs))
            image, expected = ir.render(scene, spp=16, seed=3), ir.render(dataclasses.replace(flat, material_specs=specs), spp=16, seed=3)
            assert torch.allclose(image, expected, rtol=1e-4, atol=1e-6)
            means["flat"] = ir.render(flat, spp=16, seed=3)[4:12, 4:12].mean()
    assert means["towards"] > 1.2 * means["flat"] > 1.2 * means["away"] > 0, means
