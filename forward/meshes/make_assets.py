"""Regenerate the small mesh assets of forward/: `python forward/meshes/make_assets.py`.

- torus.obj: a low-poly torus (trimesh.creation), with UVs, for forward/mesh_in_box.toml;
- lamp.glb: a glTF 2.0 binary with a grey floor quad (baseColorFactor), an emissive quad
  (emissiveFactor x KHR_materials_emissive_strength) and a perspective camera, for the glTF loader;
- ../textures/checker.png: a 4 x 4 checker for forward/textured_floor.toml.
"""

import json
import math
import struct
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).parent


def torus_obj(path: Path) -> None:
    mesh = trimesh.creation.torus(major_radius=0.35, minor_radius=0.12, major_sections=24, minor_sections=12)
    v = mesh.vertices
    uv = np.stack([0.5 + np.arctan2(v[:, 2], v[:, 0]) / (2 * math.pi), 0.5 + v[:, 1] / 0.24], axis=1)
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v] + [f"vt {a:.6f} {b:.6f}" for a, b in uv]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in mesh.faces + 1]
    path.write_text("# low-poly torus, made by make_assets.py\n" + "\n".join(lines) + "\n")


def lamp_glb(path: Path) -> None:
    quad = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], dtype=np.float32)  # y = 0, facing +y with the winding below
    light = quad * [0.25, 1, 0.25] + [0, 1.0, 0]
    light_faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.uint16)  # facing -y (down)
    floor_faces = np.array([[0, 2, 1], [0, 3, 2]], dtype=np.uint16)  # facing +y (up)
    blobs, views, accessors = [], [], []

    def add(array, target, kind, component):
        offset = sum(len(b) for b in blobs)
        data = array.tobytes()
        data += b"\0" * (-len(data) % 4)
        blobs.append(data)
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": array.nbytes, "target": target})
        acc = {"bufferView": len(views) - 1, "componentType": component, "count": len(array) if array.ndim > 1 else array.size, "type": kind}
        if kind == "VEC3":
            acc["min"], acc["max"] = array.min(0).tolist(), array.max(0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    floor_pos = add(quad, 34962, "VEC3", 5126)
    floor_idx = add(floor_faces.reshape(-1), 34963, "SCALAR", 5123)
    light_pos = add(light.astype(np.float32), 34962, "VEC3", 5126)
    light_idx = add(light_faces.reshape(-1), 34963, "SCALAR", 5123)
    doc = {
        "asset": {"version": "2.0", "generator": "invrender make_assets.py"},
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"mesh": 0, "name": "floor"},
            {"mesh": 1, "name": "lamp"},
            {"camera": 0, "name": "camera", "translation": [0, 0.5, 3.0]},
        ],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "aspectRatio": 1.5, "znear": 0.01}}],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": floor_pos}, "indices": floor_idx, "material": 0}]},
            {"primitives": [{"attributes": {"POSITION": light_pos}, "indices": light_idx, "material": 1}]},
        ],
        "materials": [
            {"name": "floor", "pbrMetallicRoughness": {"baseColorFactor": [0.6, 0.5, 0.4, 1.0], "metallicFactor": 0.0}},
            {
                "name": "lamp",
                "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1.0], "metallicFactor": 0.0},
                "emissiveFactor": [1.0, 0.8, 0.5],
                "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 12.0}},
            },
        ],
        "buffers": [{"byteLength": sum(len(b) for b in blobs)}],
        "bufferViews": views,
        "accessors": accessors,
    }
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary = b"".join(blobs)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)


def checker_png(path: Path) -> None:
    """A 4 x 4 two-tone checker (sRGB PNG) for the textured floor."""
    from PIL import Image

    cells = (np.add.outer(np.arange(4), np.arange(4)) % 2)[..., None]
    rgb = np.where(cells == 1, [200, 190, 170], [90, 110, 140]).astype(np.uint8)
    path.parent.mkdir(exist_ok=True)
    Image.fromarray(rgb, mode="RGB").save(path)


if __name__ == "__main__":
    torus_obj(HERE / "torus.obj")
    lamp_glb(HERE / "lamp.glb")
    checker_png(HERE.parent / "textures" / "checker.png")
    print("wrote", HERE / "torus.obj", HERE / "lamp.glb", HERE.parent / "textures" / "checker.png")
