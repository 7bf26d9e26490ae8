"""invrender vs Mitsuba 3 on the materials made of others and the rest of issue 33's list: the Cornell
box of forward/cornell_box.xml with, per scene (``--scene``):

- ``blend``: its tall box a ``blendbsdf`` (weight a checkerboard of 0.2 / 0.8) of an orange
  ``roughplastic`` and a GGX ``roughconductor``, its short box a ``mask`` (opacity 0.5) over a blue
  twosided ``diffuse``, its floor a ``pplastic`` (Beckmann, alpha 0.15);
- ``textured``: its tall box a GGX ``roughdielectric`` whose ``alpha`` is a checkerboard texture
  (0.05 / 0.4), its short box a ``pplastic`` of GGX with a textured ``alpha``, its floor a mask of
  opacity 0.3 over a ``roughplastic``, and below the floor a black diffuse plane that takes the
  paths through it. Without that plane, Mitsuba 3.9.1's ``path`` drops the direct light a camera
  path gathered at the masked floor when the path then passes through it into nothing (its
  ``valid_ray`` rule: a path whose only events are null ones returns 0), which invrender keeps (it
  is part of the estimate): measured +0.8% for invrender on this box with a mask(diffuse) floor of
  opacity 0.3, +0.17 +- 0.3% with the plane (64 spp, 4 seeds);
- ``delta_blend``: its tall box a ``blendbsdf`` (w = 0.5) of a perfect mirror (``conductor``) and a
  white diffuse: Mitsuba 3.9.1's blend sampler is biased for a delta lobe (blend.py's docstring),
  so the two differ there by design (invrender's is the unbiased estimate).

One XML file read by both renderers (invrender's XML subset, ``mi.load_file``); channel means with
Monte Carlo standard errors over seeds (box filter, max_depth 8), target within 1.5% (the issue's
acceptance is 1%).

    python bench/blend_mask_compare.py [--scene blend|textured|delta_blend] [--resolution 64]
                                       [--spp 256] [--mitsuba-spp 1024] [--seeds 4] [--json PATH]

Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from xml_compare import box_with, compare, parser  # noqa: E402

CHECKER = """<texture type="checkerboard" name="{name}">
                <float name="color0" value="{a}"/>
                <float name="color1" value="{b}"/>
                <transform name="to_uv"><scale x="4" y="4"/></transform>
            </texture>"""

BLEND = f"""<bsdf type="twosided"><bsdf type="blendbsdf">
            {CHECKER.format(name="weight", a=0.2, b=0.8)}
            <bsdf type="roughplastic">
                <rgb name="diffuse_reflectance" value="0.8, 0.35, 0.1"/>
            </bsdf>
            <bsdf type="roughconductor">
                <string name="distribution" value="ggx"/>
                <float name="alpha" value="0.2"/>
                <rgb name="specular_reflectance" value="0.7, 0.8, 0.9"/>
            </bsdf>
        </bsdf></bsdf>"""
MASK = """<bsdf type="mask">
            <float name="opacity" value="0.5"/>
            <bsdf type="twosided"><bsdf type="diffuse">
                <rgb name="reflectance" value="0.1, 0.25, 0.7"/>
            </bsdf></bsdf>
        </bsdf>"""
PPLASTIC = """<bsdf type="twosided"><bsdf type="pplastic">
            <rgb name="diffuse_reflectance" value="0.3, 0.5, 0.2"/>
            <float name="alpha" value="0.15"/>
        </bsdf></bsdf>"""
ROUGH_GLASS = f"""<bsdf type="roughdielectric">
            <string name="distribution" value="ggx"/>
            {CHECKER.format(name="alpha", a=0.05, b=0.4)}
        </bsdf>"""
PPLASTIC_TEXTURED = f"""<bsdf type="twosided"><bsdf type="pplastic">
            <string name="distribution" value="ggx"/>
            <rgb name="diffuse_reflectance" value="0.1, 0.25, 0.7"/>
            {CHECKER.format(name="alpha", a=0.03, b=0.3)}
        </bsdf></bsdf>"""
MASKED_FLOOR = """<bsdf type="mask">
            <float name="opacity" value="0.3"/>
            <bsdf type="twosided"><bsdf type="roughplastic">
                <rgb name="diffuse_reflectance" value="0.6, 0.6, 0.5"/>
            </bsdf></bsdf>
        </bsdf>"""
DELTA_BLEND = """<bsdf type="twosided"><bsdf type="blendbsdf">
            <float name="weight" value="0.5"/>
            <bsdf type="conductor"/>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.8, 0.8"/></bsdf>
        </bsdf></bsdf>"""

#: below the floor: a black diffuse plane (module docstring, ``textured``)
BLACK_BELOW = """<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/><translate y="-1.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf></shape>
</scene>"""

SCENES = {
    "blend": ({"large_box": BLEND, "small_box": MASK, "floor": PPLASTIC}, "blendbsdf(roughplastic, GGX roughconductor, checkerboard weight), mask(diffuse, 0.5), pplastic floor"),
    "textured": ({"large_box": ROUGH_GLASS, "small_box": PPLASTIC_TEXTURED, "floor": MASKED_FLOOR}, "roughdielectric GGX with a checkerboard alpha, pplastic GGX with a textured alpha, mask(roughplastic, 0.3) floor, a black plane below it"),
    "delta_blend": ({"large_box": DELTA_BLEND}, "blendbsdf(conductor, diffuse 0.8), w 0.5 (Mitsuba 3.9.1's sampler is biased here)"),
}


def main() -> int:
    p = parser(__doc__, spp=256, seeds=4)
    p.add_argument("--scene", choices=sorted(SCENES), default="blend")
    args = p.parse_args()
    bsdfs, description = SCENES[args.scene]
    text = box_with(bsdfs)
    if args.scene == "textured":
        text = text.replace("</scene>", BLACK_BELOW)
    return compare(args, f"blend_mask_compare_{args.scene}", "Materials of issue 33 (blendbsdf, mask, pplastic, textured roughdielectric) vs Mitsuba 3", f"Cornell box, {description}", text)


if __name__ == "__main__":
    sys.exit(main())
