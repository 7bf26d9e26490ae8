"""invrender vs Mitsuba 3 with projected images: the Cornell box lit by a ``projector`` (an image, or an
RGB value) or by a ``spot`` projecting an image, instead of its area light; channel means at high
spp with standard errors from independent seeds.

    python bench/projected_lights.py [--resolution 48] [--spp 128] [--mitsuba-spp 512] [--seeds 3]

Per light, Mitsuba's ``path`` against invrender's at max_depth 8 and 2. The Python-built scenes go
to Mitsuba through ``mitsuba_ref.scene_dict`` (the emitter's ``to_mitsuba``); the ``xml`` row
loads one Mitsuba XML file (a projector with an EXR image, ``fov_axis`` y, a scaled ``lookat``) in
both renderers. Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mitsuba_ref  # noqa: E402

import invrender as ir  # noqa: E402
from invrender.io import write_image  # noqa: E402
from invrender.scene.builtin import CORNELL_CAMERA, CORNELL_GREEN, CORNELL_RED, CORNELL_WHITE, TALL_BOX, _shape, _walls  # noqa: E402
from invrender.scene.emitters import Emitter  # noqa: E402
from invrender.scene.scene import build_scene  # noqa: E402
from invrender.scene.shapes import rotate, scale, translate  # noqa: E402


def slide() -> torch.Tensor:
    """A 24 x 32 test image: a colour ramp with a bright cross and a dark corner (orientation shows)."""
    h, w = 24, 32
    y, x = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    img = torch.stack([0.2 + 1.5 * x, 0.3 + y, 1.2 - x * y], dim=2)
    img[h // 2 - 2 : h // 2 + 2] *= 3.0
    img[:, w // 3 - 1 : w // 3 + 2] *= 3.0
    img[: h // 4, : w // 4] = 0.05
    return img


LIGHTS = {
    "projector (image)": lambda: Emitter.of("projector", emission=slide(), position=[0.0, 0.9, 0.5], direction=[0.1, -1.0, -0.6], up=[0.0, 0.0, -1.0], fov=70.0, scale=1.5),
    "projector (RGB)": lambda: Emitter.of("projector", emission=[0.8, 0.7, 0.5], position=[-0.3, 0.85, 0.6], direction=[0.4, -1.0, -0.5], up=[0.0, 1.0, 0.0], fov=45.0, scale=2.0),
    "spot (image)": lambda: Emitter.of("spot", emission=slide() * 6.0, position=[0.0, 0.9, 0.4], direction=[0.15, -1.0, -0.3], up=[1.0, 0.0, 0.0], cutoff_angle=40.0, beam_width=25.0),
}

XML = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 0, 3.9" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/><rfilter type="box"/></film>
  </sensor>
  <emitter type="projector">
    <texture type="bitmap" name="irradiance"><string name="filename" value="slide.exr"/></texture>
    <float name="fov" value="50"/><string name="fov_axis" value="y"/><float name="scale" value="0.8"/>
    <transform name="to_world"><scale value="1.5"/><lookat origin="0.2, 0.9, 0.8" target="-0.1, -0.6, -0.4" up="0, 1, 0"/></transform>
  </emitter>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><translate y="-1"/></transform><bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><translate z="-1"/></transform><bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.5"/></bsdf></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.3"/><rotate y="1" angle="30"/><translate x="0.3" y="-0.7" z="0.1"/></transform><bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.3, 0.2"/></bsdf></shape>
</scene>
"""


def cornell(light: str, resolution: int) -> ir.Scene:
    shapes = [
        *_walls(),
        _shape("cube", translate([0.335, -0.7, 0.38]) @ rotate([0, 1, 0], -17) @ scale(0.3), "white"),
        _shape("cube", TALL_BOX, "white"),
    ]
    materials = {"white": CORNELL_WHITE, "red": CORNELL_RED, "green": CORNELL_GREEN}
    return build_scene(shapes, materials, {"lamp": LIGHTS[light]()}, CORNELL_CAMERA, (resolution, resolution), name="cornell_projected")


def stats(means: list[list[float]]) -> list[tuple[float, float]]:
    """Per channel: (mean over seeds, standard error)."""
    return [(statistics.fmean(c), statistics.stdev(c) / len(c) ** 0.5) for c in zip(*means)]


def row(label: str, depth: int, ours: list, theirs: list) -> None:
    cells = []
    for (a, sa), (b, sb) in zip(stats(ours), stats(theirs)):
        rel = a / b - 1.0
        err = (a / b) * ((sa / a) ** 2 + (sb / b) ** 2) ** 0.5
        cells.append(f"{b:.5f} / {a:.5f} ({100 * rel:+.2f} ± {100 * err:.2f}%)")
    print(f"| {label} | {depth} | " + " | ".join(cells) + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=48)
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--mitsuba-spp", type=int, default=512)
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    if not mitsuba_ref.available():
        sys.exit("Mitsuba 3 is not available (bench/README.md)")
    mi, _ = mitsuba_ref._require()
    print(f"# {mitsuba_ref.label()}; {args.resolution}^2, invrender {args.spp} spp, Mitsuba {args.mitsuba_spp} spp, {args.seeds} seeds")
    print("| light | max_depth | R: Mitsuba / invrender | G | B |")
    print("|---|---|---|---|---|")
    for light in LIGHTS:
        s = cornell(light, args.resolution)
        for depth in (8, 2):
            ours = [ir.render(s, spp=args.spp, max_depth=depth, seed=k, progress=False).mean((0, 1)).tolist() for k in range(args.seeds)]
            mi_scene = mi.load_dict(mitsuba_ref.scene_dict(s, args.mitsuba_spp, depth))
            theirs = [mitsuba_ref.render(mi_scene, args.mitsuba_spp, seed=1000 + k).reshape(-1, 3).mean(0).tolist() for k in range(args.seeds)]
            row(light, depth, ours, theirs)
    with tempfile.TemporaryDirectory() as folder:
        write_image(Path(folder) / "slide.exr", slide())
        path = Path(folder) / "projector.xml"
        path.write_text(XML.format(res=args.resolution))
        s = ir.load_scene(str(path))
        for depth in (8, 2):
            ours = [ir.render(s, spp=args.spp, max_depth=depth, seed=k, progress=False, filter="box").mean((0, 1)).tolist() for k in range(args.seeds)]
            mi_scene = mi.load_file(str(path))
            theirs = []
            for k in range(args.seeds):
                params = mi.load_dict({"type": "path", "max_depth": depth})
                img = mi.render(mi_scene, integrator=params, spp=args.mitsuba_spp, seed=1000 + k)
                theirs.append(np.asarray(img).reshape(-1, 3).mean(0).tolist())
            row("xml: projector (EXR, fov_axis y, scaled lookat)", depth, ours, theirs)


if __name__ == "__main__":
    main()
