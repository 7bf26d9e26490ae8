"""invrender vs Mitsuba 3 on anisotropic roughness (the UV tangent frame): the Cornell box of
forward/cornell_box.xml with its tall box a GGX ``roughconductor`` (gold, alpha_u 0.05, alpha_v
0.4), its short box a Beckmann ``roughdielectric`` (alpha_u 0.3, alpha_v 0.04) and its floor an
anisotropic ``principled`` metal (roughness 0.4, anisotropic 0.9, metallic 0.8), one XML file read by
both renderers: channel means with Monte Carlo standard errors over seeds (box filter, max_depth 8),
target within 1.5%. The floor and the boxes' faces have Mitsuba's UVs (dp/du along a box face's
edge, the floor's x), so their highlights stretch the same way in both only if the frames agree.

    python bench/anisotropic_compare.py [--resolution 64] [--spp 64] [--mitsuba-spp 256] [--seeds 2]
                                        [--write PATH] [--json PATH]

Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from xml_compare import box_with, compare, parser  # noqa: E402

CONDUCTOR = """<bsdf type="twosided"><bsdf type="roughconductor">
            <string name="distribution" value="ggx"/>
            <string name="material" value="Au"/>
            <float name="alpha_u" value="0.05"/>
            <float name="alpha_v" value="0.4"/>
        </bsdf></bsdf>"""
DIELECTRIC = """<bsdf type="roughdielectric">
            <float name="alpha_u" value="0.3"/>
            <float name="alpha_v" value="0.04"/>
        </bsdf>"""
PRINCIPLED = """<bsdf type="twosided"><bsdf type="principled">
            <rgb name="base_color" value="0.8, 0.6, 0.3"/>
            <float name="roughness" value="0.4"/>
            <float name="anisotropic" value="0.9"/>
            <float name="metallic" value="0.8"/>
        </bsdf></bsdf>"""


def main() -> int:
    args = parser(__doc__, spp=64, seeds=2).parse_args()
    text = box_with({"large_box": CONDUCTOR, "small_box": DIELECTRIC, "floor": PRINCIPLED})
    return compare(
        args, "anisotropic_compare", "Anisotropic roughness (roughconductor, roughdielectric, principled) vs Mitsuba 3",
        "Cornell box, anisotropic GGX gold tall box, Beckmann rough glass short box, anisotropic principled floor", text,
    )  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
