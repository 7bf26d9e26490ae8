"""invrender vs Mitsuba 3 on rough glass: the Cornell box of forward/cornell_box.xml with its tall box
a GGX ``roughdielectric`` (alpha 0.2, bk7 over air, Mitsuba's default indices) and its short box a
Beckmann one (Mitsuba's default distribution, alpha 0.1, ``int_ior`` 1.33, a tinted
``specular_transmittance``), one XML file read by both renderers (invrender's XML subset,
``mi.load_file``), and the same scene as invrender loaded it, converted back for Mitsuba by bench's
converter (each type's ``to_mitsuba``): channel means with Monte Carlo standard errors over seeds
(box filter, max_depth 8), target within 1.5%.

    python bench/roughdielectric_compare.py [--resolution 64] [--spp 256] [--mitsuba-spp 1024] [--seeds 4]
                                            [--write PATH] [--json PATH]

``--write`` also saves the scene file. Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from xml_compare import box_with, compare, parser  # noqa: E402

GGX = """<bsdf type="roughdielectric">
            <string name="distribution" value="ggx"/>
            <float name="alpha" value="0.2"/>
        </bsdf>"""
BECKMANN = """<bsdf type="roughdielectric">
            <float name="alpha" value="0.1"/>
            <float name="int_ior" value="1.33"/>
            <rgb name="specular_transmittance" value="0.9, 0.8, 0.6"/>
        </bsdf>"""


def scene_xml() -> str:
    """forward/cornell_box.xml with the tall box and the short box replaced."""
    return box_with({"large_box": GGX, "small_box": BECKMANN})


def main() -> int:
    args = parser(__doc__, spp=256, seeds=4).parse_args()
    return compare(
        args, "roughdielectric_compare", "Rough glass (roughdielectric GGX and Beckmann) vs Mitsuba 3",
        "Cornell box, GGX roughdielectric tall box (alpha 0.2, bk7), Beckmann roughdielectric short box (alpha 0.1, ior 1.33, tinted)", scene_xml(), converted=True,
    )  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
