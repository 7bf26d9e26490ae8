"""invrender vs Mitsuba 3 on plastics: the Cornell box of forward/cornell_box.xml with its tall box a
``roughplastic`` of Mitsuba's defaults (Beckmann, alpha 0.1) in orange, its short box a smooth
``plastic`` in blue (``int_ior`` 1.6, ``nonlinear``) and its floor a GGX ``roughplastic``
(alpha 0.3, ``specular_reflectance`` 0.8), one XML file read by both renderers (invrender's XML
subset, ``mi.load_file``), and the same scene as invrender loaded it, converted back for Mitsuba by
bench's converter (each type's ``to_mitsuba``): channel means with Monte Carlo standard errors over
seeds (box filter, max_depth 8), target within 1.5%.

    python bench/plastic_compare.py [--resolution 64] [--spp 256] [--mitsuba-spp 1024] [--seeds 4]
                                    [--write PATH] [--json PATH]

``--write`` also saves the scene file. Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from xml_compare import box_with, compare, parser  # noqa: E402

ROUGH = """<bsdf type="roughplastic">
            <rgb name="diffuse_reflectance" value="0.8, 0.35, 0.1"/>
        </bsdf>"""
SMOOTH = """<bsdf type="twosided"><bsdf type="plastic">
            <rgb name="diffuse_reflectance" value="0.1, 0.25, 0.7"/>
            <float name="int_ior" value="1.6"/>
            <boolean name="nonlinear" value="true"/>
        </bsdf></bsdf>"""
FLOOR = """<bsdf type="twosided"><bsdf type="roughplastic">
            <string name="distribution" value="ggx"/>
            <float name="alpha" value="0.3"/>
            <rgb name="diffuse_reflectance" value="0.6, 0.6, 0.5"/>
            <rgb name="specular_reflectance" value="0.8, 0.8, 0.8"/>
        </bsdf></bsdf>"""


def scene_xml() -> str:
    """forward/cornell_box.xml with the tall box, the short box and the floor replaced."""
    return box_with({"large_box": ROUGH, "small_box": SMOOTH, "floor": FLOOR})


def main() -> int:
    args = parser(__doc__, spp=256, seeds=4).parse_args()
    return compare(args, "plastic_compare", "Plastics (plastic, roughplastic Beckmann and GGX) vs Mitsuba 3", "Cornell box, Beckmann roughplastic (alpha 0.1), smooth plastic (ior 1.6, nonlinear), GGX roughplastic floor (alpha 0.3)", scene_xml(), converted=True)


if __name__ == "__main__":
    sys.exit(main())
