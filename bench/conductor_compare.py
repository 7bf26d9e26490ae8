"""invrender vs Mitsuba 3 on conductors as scene files write them: the Cornell box of
forward/cornell_box.xml with its tall box a ``roughconductor`` of Mitsuba's defaults (Beckmann,
``sample_visible``) in gold (``material = "Au"``, alpha 0.2), its short box a smooth ``conductor``
in copper (``material = "Cu"``) and its floor a ``checkerboard`` (``to_uv`` scale 4), one XML file
read by both renderers (invrender's XML subset, ``mi.load_file``): channel means with Monte Carlo
standard errors over seeds (box filter, max_depth 8), target within 1.5%.

    python bench/conductor_compare.py [--resolution 64] [--spp 1024] [--mitsuba-spp 4096] [--seeds 8]
                                      [--write PATH] [--json PATH]

``--write`` also saves the scene file. Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from xml_compare import box_with, compare, parser  # noqa: E402

GOLD = """<bsdf type="roughconductor">
            <string name="material" value="Au"/>
            <float name="alpha" value="0.2"/>
        </bsdf>"""
COPPER = """<bsdf type="conductor">
            <string name="material" value="Cu"/>
        </bsdf>"""
CHECKER = """<bsdf type="twosided"><bsdf type="diffuse">
            <texture type="checkerboard" name="reflectance">
                <rgb name="color0" value="0.8, 0.8, 0.8"/>
                <rgb name="color1" value="0.2, 0.3, 0.6"/>
                <transform name="to_uv"><scale x="4" y="4"/></transform>
            </texture>
        </bsdf></bsdf>"""


def scene_xml() -> str:
    """forward/cornell_box.xml with the tall box, the short box and the floor replaced."""
    return box_with({"large_box": GOLD, "small_box": COPPER, "floor": CHECKER})


def main() -> int:
    args = parser(__doc__, spp=1024, seeds=8).parse_args()
    return compare(args, "conductor_compare", "Conductors (named metals, Beckmann) and checkerboards vs Mitsuba 3", "Cornell box, gold Beckmann roughconductor (alpha 0.2), copper conductor, checkerboard floor", scene_xml())


if __name__ == "__main__":
    sys.exit(main())
