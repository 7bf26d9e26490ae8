"""invrender vs Mitsuba 3 on the principled materials: the Cornell box of forward/cornell_box.xml
with principled blocks, one XML file read by both renderers (invrender's XML subset,
``mi.load_file``): channel means with Monte Carlo standard errors over seeds (box filter,
max_depth 8), target within 1% (issue 33).

Two scenes:

- ``opaque``: the tall box a metallic principled (metallic 0.7, roughness 0.35, clearcoat 0.6,
  spec_tint as a colour), the short box a ``twosided`` principled as the Blender exporter writes it
  (``specular``, ``spec_trans`` 0, sheen 0.5 tinted, roughness 0.6), the floor a ``twosided``
  anisotropic principled (anisotropic 0.6, roughness 0.4, flatness 0.3);
- ``transmissive``: the tall box a ``principledthin`` sheet material (spec_trans 0.5, diff_trans
  0.6, eta 1.4), the short box a principled with spec_trans 0.7 (eta 1.45, roughness 0.3), the floor
  the opaque scene's.

    python bench/principled_cornell.py [--resolution 64] [--spp 64] [--mitsuba-spp 1024] [--seeds 4]
                                       [--json PATH] [--scene opaque|transmissive|both]

Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from xml_compare import box_with, compare, parser  # noqa: E402

METAL = """<bsdf type="principled">
            <rgb name="base_color" value="0.9, 0.55, 0.25"/>
            <float name="metallic" value="0.7"/>
            <float name="roughness" value="0.35"/>
            <float name="clearcoat" value="0.6"/>
            <float name="clearcoat_gloss" value="0.5"/>
            <rgb name="spec_tint" value="0.3, 0.5, 0.7"/>
        </bsdf>"""
BLENDER = """<bsdf type="twosided"><bsdf type="principled">
            <rgb name="base_color" value="0.15, 0.35, 0.75"/>
            <float name="specular" value="0.5"/>
            <float name="spec_trans" value="0.0"/>
            <float name="roughness" value="0.6"/>
            <float name="sheen" value="0.5"/>
            <float name="sheen_tint" value="0.5"/>
        </bsdf></bsdf>"""
FLOOR = """<bsdf type="twosided"><bsdf type="principled">
            <rgb name="base_color" value="0.7, 0.7, 0.6"/>
            <float name="anisotropic" value="0.6"/>
            <float name="roughness" value="0.4"/>
            <float name="flatness" value="0.3"/>
        </bsdf></bsdf>"""
SHEET = """<bsdf type="principledthin">
            <rgb name="base_color" value="0.4, 0.75, 0.3"/>
            <float name="spec_trans" value="0.5"/>
            <float name="diff_trans" value="0.6"/>
            <float name="eta" value="1.4"/>
            <float name="roughness" value="0.4"/>
        </bsdf>"""
GLASS = """<bsdf type="principled">
            <rgb name="base_color" value="0.85, 0.9, 1.0"/>
            <float name="spec_trans" value="0.7"/>
            <float name="eta" value="1.45"/>
            <float name="roughness" value="0.3"/>
        </bsdf>"""

SCENES = {
    "opaque": ("Cornell box, principled metal + clearcoat, twosided principled (Blender's form) with sheen, anisotropic principled floor", {"large_box": METAL, "small_box": BLENDER, "floor": FLOOR}),
    "transmissive": ("Cornell box, principledthin sheet box, principled with spec_trans 0.7, anisotropic principled floor", {"large_box": SHEET, "small_box": GLASS, "floor": FLOOR}),
}


def main() -> int:
    p = parser(__doc__, spp=64, seeds=4)
    p.add_argument("--scene", choices=[*SCENES, "both"], default="both")
    args = p.parse_args()
    code = 0
    for name, (title, bsdfs) in SCENES.items():
        if args.scene in (name, "both"):
            code = max(code, compare(args, f"principled_{name}", f"Principled materials ({name}) vs Mitsuba 3", title, box_with(bsdfs), converted=True))
    return code


if __name__ == "__main__":
    sys.exit(main())
