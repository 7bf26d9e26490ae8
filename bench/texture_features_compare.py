"""Issue 33's scene-loading features side by side with Mitsuba 3: a bitmap read with ``to_uv``,
``filter_type="nearest"`` and each ``wrap_mode``, a ``mesh_attribute`` (PLY vertex colours) and a
``shapegroup`` placed by two ``instance``s; one XML file per case read by both renderers, a
constant environment, path tracing to depth 4, box filter.

    python bench/texture_features_compare.py [--resolution 32] [--spp 256]

Prints each case's channel means and their relative difference (percent). Needs Mitsuba 3
(``llvm_ad_rgb``); the tests check the same features without it.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch

import invrender as ir

SCENE = """<scene version="3.0.0">
<sensor type="perspective"><float name="fov" value="{fov}"/><transform name="to_world"><lookat origin="0, 0, {z}" target="0, 0, 0" up="0, 1, 0"/></transform>
<film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/><rfilter type="box"/></film></sensor>
<integrator type="path"><integer name="max_depth" value="4"/></integrator>
<emitter type="constant"/>
{body}
</scene>"""

BITMAP = """<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="t.exr"/>
<string name="filter_type" value="{filter}"/><string name="wrap_mode" value="{wrap}"/>
<transform name="to_uv"><scale x="2.3" y="1.7"/><translate x="-0.4" y="0.2"/></transform></texture></bsdf></shape>"""

MESH_ATTRIBUTE = """<shape type="ply"><string name="filename" value="q.ply"/><bsdf type="diffuse">
<texture type="mesh_attribute" name="reflectance"><string name="name" value="vertex_color"/></texture></bsdf></shape>"""

INSTANCES = """<bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.8, 0.2, 0.2"/></bsdf>
<shape type="shapegroup" id="g">
  <shape type="cube"><transform name="to_world"><scale value="0.5"/></transform><ref id="red"/></shape>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><translate y="-0.5"/></transform></shape>
</shape>
<shape type="instance"><ref id="g"/><transform name="to_world"><translate x="-1.2"/></transform></shape>
<shape type="instance"><ref id="g"/><transform name="to_world"><rotate y="1" angle="30"/><scale value="0.8"/><translate x="1.2"/></transform></shape>"""


def write_data(folder: Path) -> None:
    rng = np.random.default_rng(1)
    ir.write_image(folder / "t.exr", torch.tensor(rng.uniform(0.05, 0.95, (5, 7, 3)), dtype=torch.float32))
    colours = [(0.1, 0.2, 0.3), (0.9, 0.1, 0.1), (0.2, 0.8, 0.2), (0.5, 0.5, 0.9)]
    corners = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    lines = ["ply", "format ascii 1.0", "element vertex 4", *(f"property float {a}" for a in "xyzrgb"), "element face 2", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(map(str, (*p, *c))) for p, c in zip(corners, colours)] + ["3 0 1 2", "3 0 2 3", ""]
    (folder / "q.ply").write_text("\n".join(lines))


def cases() -> dict[str, tuple[str, float, float]]:
    out = {f"bitmap {f} {w}": (BITMAP.format(filter=f, wrap=w), 40.0, 3.0) for f in ("nearest", "bilinear") for w in ("repeat", "clamp", "mirror")}
    out["mesh_attribute vertex_color"] = (MESH_ATTRIBUTE, 40.0, 3.0)
    out["shapegroup + 2 instances"] = (INSTANCES, 50.0, 5.0)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--resolution", type=int, default=32)
    p.add_argument("--spp", type=int, default=256)
    args = p.parse_args()
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    print(f"| case | invrender means | Mitsuba {mi.__version__} means | difference (%) |\n|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        write_data(folder)
        for name, (body, fov, z) in cases().items():
            path = folder / "scene.xml"
            path.write_text(SCENE.format(fov=fov, z=z, res=args.resolution, body=body))
            ours = ir.render(ir.load_scene(path), spp=args.spp, seed=0).double().mean((0, 1)).numpy()
            theirs = np.asarray(mi.render(mi.load_file(str(path)), spp=args.spp, seed=0), dtype=np.float64).mean((0, 1))
            diff = 100 * (ours - theirs) / theirs
            fmt = lambda v: ", ".join(f"{x:.4f}" for x in v)  # noqa: E731
            print(f"| {name} | {fmt(ours)} | {fmt(theirs)} | {', '.join(f'{d:+.2f}' for d in diff)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
