"""invrender vs Mitsuba 3 on perturbed shading normals: a plane with a ``normalmap`` (a diffuse and a
rough-plastic BSDF under it, ``twosided`` both ways round) and a sphere with a ``bumpmap`` (a
Beckmann ``roughconductor`` under it) beside a plane with a ``bumpmap`` over ``diffuse``, lit by a
rectangular area light at a low angle and a dim constant sky, one XML file per scene read by both
renderers: channel means with Monte Carlo standard errors over seeds (box filter, max_depth 8),
target within 1% (``--json PATH`` writes the normal maps' figures there and the bump maps' to
bumpmap_compare.json beside it). The textures are made here (8-bit PNGs read raw, as Mitsuba's files read them):
a normal map of a bumpy sine field and a height map of the same field.

    python bench/normalmap_compare.py [--resolution 64] [--spp 64] [--mitsuba-spp 256] [--seeds 2]
                                      [--json PATH]

Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from xml_compare import compare, parser  # noqa: E402

SIZE = 64


def height(size: int = SIZE) -> np.ndarray:
    """(size, size) the height field in [0, 1] (row 0 at the image's top)."""
    y, x = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size, indexing="ij")
    return 0.5 + 0.25 * np.sin(2 * np.pi * 3 * x) * np.sin(2 * np.pi * 2 * y) + 0.25 * np.sin(2 * np.pi * 5 * (x + y))


def normals(size: int = SIZE, strength: float = 0.15) -> np.ndarray:
    """(size, size, 3) unit tangent-space normals of the height field (x along the image's columns,
    y up the image), tilted by ``strength`` per unit slope."""
    h = height(size)
    dx = np.gradient(h, axis=1) * size * strength
    dy = -np.gradient(h, axis=0) * size * strength
    n = np.stack([-dx, -dy, np.ones_like(h)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def write_png(path: Path, rgb: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(np.clip(np.round(rgb * 255), 0, 255).astype(np.uint8)).save(path)


HEAD = """<scene version="3.0.0">
    <default name="spp" value="16"/>
    <default name="res" value="64"/>
    <integrator type="path"><integer name="max_depth" value="8"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="50"/>
        <transform name="to_world"><lookat origin="0, -2.8, 2.4" target="0, 0, 0.3" up="0, 0, 1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/><rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.02, 0.025, 0.03"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.6"/><rotate y="1" angle="-70"/><translate x="2.4" y="0.5" z="1.0"/></transform>
        <emitter type="area"><rgb name="radiance" value="12, 11, 9"/></emitter>
    </shape>
"""


def normalmap_scene(folder: Path) -> str:
    path = folder / "normals.png"
    write_png(path, (normals() + 1) / 2)
    tex = f'<texture name="normalmap" type="bitmap"><string name="filename" value="{path}"/><boolean name="raw" value="true"/></texture>'
    return HEAD + f"""
    <shape type="rectangle">
        <transform name="to_world"><scale x="1.0" y="1.0"/><translate x="-1.05"/></transform>
        <bsdf type="twosided"><bsdf type="normalmap">{tex}
            <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.7, 0.5"/></bsdf>
        </bsdf></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><rotate z="1" angle="30"/><translate x="1.05"/></transform>
        <bsdf type="normalmap">{tex}
            <bsdf type="twosided"><bsdf type="roughplastic"><float name="alpha" value="0.2"/><rgb name="diffuse_reflectance" value="0.3, 0.5, 0.7"/></bsdf></bsdf>
        </bsdf>
    </shape>
</scene>
"""


def bumpmap_scene(folder: Path) -> str:
    path = folder / "height.png"
    write_png(path, np.repeat(height()[..., None], 3, axis=-1))
    tex = f'<texture type="bitmap"><string name="filename" value="{path}"/><boolean name="raw" value="true"/></texture>'
    return HEAD + f"""
    <shape type="sphere">
        <transform name="to_world"><scale value="0.8"/><rotate x="1" angle="20"/><translate x="0.9" z="0.8"/></transform>
        <bsdf type="bumpmap">{tex}<float name="scale" value="0.3"/>
            <bsdf type="roughconductor"><float name="alpha" value="0.25"/><string name="material" value="Cu"/></bsdf>
        </bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><translate x="-1.05"/></transform>
        <bsdf type="twosided"><bsdf type="bumpmap">{tex}<float name="scale" value="0.1"/>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.7, 0.5"/></bsdf>
        </bsdf></bsdf>
    </shape>
</scene>
"""


def main() -> int:
    args = parser(__doc__, spp=64, seeds=2).parse_args()
    worst, json_path = 0, args.json
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name, heading, scene in (
            ("normalmap_compare", "Normal maps (plane, diffuse and roughplastic) vs Mitsuba 3", normalmap_scene(folder)),
            ("bumpmap_compare", "Bump maps (sphere, roughconductor; plane, diffuse) vs Mitsuba 3", bumpmap_scene(folder)),
        ):
            # --json names the normal maps' file; the bump maps' goes beside it
            args.json = None if json_path is None else (json_path if name == "normalmap_compare" else Path(json_path).with_name("bumpmap_compare.json"))
            worst = max(worst, compare(args, name, heading, heading.split(" vs ")[0], scene))
    return worst


if __name__ == "__main__":
    sys.exit(main())
