"""The principled materials (invrender/plugins/bsdfs/principled.py, principledthin.py): eval and pdf
against Mitsuba 3.9.1's values (computed with mitsuba's llvm_ad_rgb variant by
bench/principled_compare.py's settings and hard-coded here: no Mitsuba at test time), sampling
against pdf, energy bounds, the gradient of a render against finite differences, the Mitsuba
loader (twosided, specular -> eta) and its one-line errors.

The registry-driven conformance suite (test_conformance.py) also checks them at their defaults."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.core.bsdf import ShadingPoint
from invrender.errors import SceneError
from invrender.plugins.bsdfs import checks
from invrender.plugins.bsdfs.principled import Principled
from invrender.plugins.bsdfs.principledthin import PrincipledThin

BOX = Path(__file__).parents[2] / "forward" / "cornell_box.xml"

#: bench/principled_compare.py's settings (Mitsuba properties; specular read as eta as the loader does)
SETTINGS = {
    "default": ("principled", {}, False),
    "metal": ("principled", {"base_color": [0.9, 0.6, 0.2], "metallic": 0.8, "roughness": 0.3, "spec_tint": 0.5, "specular": 0.7}, False),
    "aniso": ("principled", {"base_color": [0.2, 0.5, 0.8], "roughness": 0.6, "anisotropic": 0.7, "metallic": 0.3}, False),
    "sheen_coat": ("principled", {"base_color": [0.7, 0.3, 0.3], "sheen": 0.8, "sheen_tint": 0.6, "clearcoat": 0.9, "clearcoat_gloss": 0.7, "roughness": 0.4}, False),
    "glass": ("principled", {"base_color": [0.9, 0.95, 1.0], "spec_trans": 1.0, "eta": 1.45, "roughness": 0.2}, False),
    "mixed": ("principled", {"base_color": [0.5, 0.8, 0.3], "spec_trans": 0.4, "metallic": 0.2, "clearcoat": 0.5, "sheen": 0.3, "roughness": 0.5, "anisotropic": 0.3, "flatness": 0.4}, False),
    "twosided": ("principled", {"base_color": [0.3, 0.6, 0.9], "roughness": 0.35, "spec_tint": 0.3, "sheen": 0.4, "specular": 0.4}, True),
    "everything": ("principled", {"base_color": [0.8, 0.4, 0.6], "metallic": 0.5, "specular": 0.6, "roughness": 0.25, "spec_tint": 0.4, "anisotropic": 0.5,
                                  "sheen": 0.3, "sheen_tint": 0.2, "clearcoat": 0.6, "clearcoat_gloss": 0.3, "spec_trans": 0.4}, False),
    "thin_default": ("principledthin", {}, False),
    "thin_leaf": ("principledthin", {"base_color": [0.3, 0.7, 0.2], "roughness": 0.45, "spec_trans": 0.3, "diff_trans": 0.8, "sheen": 0.5, "sheen_tint": 0.4, "spec_tint": 0.3}, False),
    "thin_aniso": ("principledthin", {"base_color": [0.8, 0.8, 0.9], "roughness": 0.3, "anisotropic": 0.6, "spec_trans": 0.7, "eta": 1.33, "flatness": 0.5, "diff_trans": 1.5}, False),
}

#: (setting, Mitsuba's si.wi (towards the camera), wo (towards the light), both local and rounded
#: (normalized before use), Mitsuba's eval (RGB) and pdf there)
MITSUBA = [
    ('default', [-0.81172, 0.20319, 0.54757], [-0.59432, -0.69731, 0.40069], [0.06612773, 0.06612773, 0.06612773], 0.07200736),
    ('default', [0.35356, -0.62485, 0.6961], [0.71476, -0.68629, 0.13462], [0.02575511, 0.02575511, 0.02575511], 0.02668137),
    ('default', [0.56449, 0.56732, 0.59958], [0.66788, 0.13427, 0.73206], [0.1181332, 0.1181332, 0.1181332], 0.1293555),
    ('metal', [0.84016, -0.34958, 0.41463], [-0.97144, 0.20948, 0.11147], [0.07287215, 0.05433789, 0.02962552], 0.08845979),
    ('metal', [-0.72394, -0.04621, 0.68831], [-0.54959, -0.82398, 0.13787], [0.008776782, 0.005853896, 0.001956712], 0.008597773),
    ('metal', [-0.89615, 0.3186, 0.30888], [0.1376, -0.22938, 0.96356], [0.07424141, 0.04956357, 0.01665977], 0.07439038),
    ('aniso', [-0.71839, -0.39482, 0.57274], [0.50852, 0.22901, 0.83004], [0.08830693, 0.1922525, 0.2961981], 0.4359187),
    ('aniso', [0.33871, 0.73781, 0.58388], [-0.5262, -0.8336, 0.16799], [0.05988371, 0.09452745, 0.1291712], 0.3211361),
    ('aniso', [0.70154, 0.69966, 0.1353], [0.74805, -0.6528, 0.11946], [0.0158245, 0.03433379, 0.05284308], 0.1677924),
    ('sheen_coat', [0.60966, -0.70715, 0.35814], [0.28253, 0.41396, 0.86534], [0.1954858, 0.08532752, 0.08532752], 0.1433903),
    ('sheen_coat', [-0.15041, -0.01568, 0.9885], [-0.90648, 0.34292, 0.24637], [0.05617444, 0.02440788, 0.02440788], 0.04195773),
    ('sheen_coat', [-0.44732, 0.38247, 0.80847], [-0.82647, -0.51362, 0.23054], [0.0524088, 0.02268896, 0.02268896], 0.03744458),
    ('glass', [-0.39881, 0.74777, -0.53084], [0.92498, -0.19617, -0.32546], [0.001216743, 0.001216743, 0.001216743], 0.001220837),
    ('glass', [0.53739, 0.05064, -0.84181], [-0.81651, 0.0328, -0.5764], [0.08556749, 0.08556749, 0.08556749], 0.08563623),
    ('glass', [-0.50796, -0.71347, -0.48264], [0.23232, 0.93666, 0.2621], [0.004752704, 0.004882939, 0.00500979], 0.00239563),
    ('mixed', [-0.04897, -0.21942, 0.9744], [0.81027, 0.20461, 0.54918], [0.05685171, 0.08787574, 0.03616903], 0.116408),
    ('mixed', [-0.76164, 0.26878, 0.58963], [-0.01432, -0.86129, 0.50791], [0.04642194, 0.0730969, 0.02863865], 0.06793296),
    ('mixed', [0.03253, 0.45262, 0.89111], [0.23948, 0.12471, -0.96286], [0.0009466655, 0.001197448, 0.000733284], 0.001879644),
    ('twosided', [-0.09331, 0.5295, -0.84316], [0.25976, -0.49468, -0.82935], [0.1443581, 0.2351364, 0.3259146], 1.255668),
    ('twosided', [-0.67938, 0.58666, -0.44076], [-0.25193, 0.9514, -0.17708], [0.01796808, 0.03586842, 0.05376876], 0.02984531),
    ('twosided', [-0.91577, -0.08828, -0.39189], [-0.87113, 0.15639, -0.46549], [0.04563947, 0.09117976, 0.13672], 0.07632815),
    ('everything', [0.73972, -0.62509, 0.24916], [-0.37617, -0.82203, 0.42751], [0.03147051, 0.01581731, 0.02364391], 0.02941858),
    ('everything', [-0.33803, 0.9064, -0.25332], [0.22109, -0.93461, -0.2786], [0.210326, 0.210326, 0.210326], 1.059109),
    ('everything', [0.17096, -0.35634, -0.91858], [0.02426, 0.83842, 0.54448], [0.002071482, 0.001464759, 0.001793956], 0.004757645),
    ('thin_default', [0.92955, -0.12723, 0.34606], [0.91893, 0.17686, 0.35254], [0.06252597, 0.06252597, 0.06252597], 0.1122172),
    ('thin_default', [0.62028, -0.61944, -0.48119], [0.52528, 0.18053, -0.83156], [0.1338798, 0.1338798, 0.1338798], 0.2646935),
    ('thin_default', [-0.71249, -0.22066, -0.66608], [-0.89479, -0.3822, -0.23081], [0.04113953, 0.04113953, 0.04113953], 0.07346913),
    ('thin_leaf', [0.31628, 0.24604, -0.91621], [0.55628, 0.35822, -0.74983], [0.03044287, 0.0706423, 0.02039301], 0.1055219),
    ('thin_leaf', [0.04689, -0.46768, -0.88265], [-0.59382, 0.70746, -0.38325], [0.01640746, 0.0370344, 0.01125073], 0.06313521),
    ('thin_leaf', [-0.83134, 0.49326, 0.25608], [0.8161, 0.50008, -0.28966], [0.007744929, 0.0180715, 0.005163286], 0.02581643),
    ('thin_aniso', [0.19813, 0.10705, 0.97431], [-0.11799, -0.77318, 0.62311], [0.01068869, 0.01068869, 0.01201352], 0.01701178),
    ('thin_aniso', [0.81579, -0.1652, -0.55426], [-0.64197, -0.16306, -0.74919], [0.01512644, 0.01512644, 0.01686982], 0.03771949),
    ('thin_aniso', [0.22701, 0.52717, 0.81888], [-0.20268, -0.79572, -0.57074], [0.03752194, 0.03752194, 0.04221218], 0.04397503),
]


def material(setting: str):
    plugin, props, twosided = SETTINGS[setting]
    entries = {k: v for k, v in props.items() if k != "specular"}
    if plugin == "principled" and "eta" not in props:
        entries["eta"] = 2.0 / (1.0 - math.sqrt(0.08 * props.get("specular", 0.5))) - 1.0
    if twosided:
        entries["two_sided"] = True
    return checks.instance(Principled if plugin == "principled" else PrincipledThin, **entries)


def point(wi_mitsuba) -> ShadingPoint:
    """invrender's view of Mitsuba's si.wi (local, normal +z): wo = si.wi, the normal turned to it."""
    wo = torch.tensor(wi_mitsuba, dtype=torch.float32)
    front = wo[:, 2] > 0
    n = torch.zeros_like(wo)
    n[:, 2] = torch.where(front, 1.0, -1.0)
    zeros = torch.zeros(wo.shape[0], dtype=torch.int64)
    return ShadingPoint(wo, n, n, front, torch.zeros(wo.shape[0], 2), zeros, zeros)


def unit(rows) -> np.ndarray:
    v = np.asarray(rows, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("setting", list(SETTINGS))
def test_eval_and_pdf_match_mitsuba(setting):
    rows = [r for r in MITSUBA if r[0] == setting]
    assert rows
    bsdf = material(setting)
    sp = point(unit([r[1] for r in rows]))
    wi = torch.tensor(unit([r[2] for r in rows]), dtype=torch.float32)
    f, pdf = bsdf.eval(sp, wi).double(), bsdf.pdf(sp, wi).double()
    want_f = torch.tensor([r[3] for r in rows], dtype=torch.float64)
    want_pdf = torch.tensor([r[4] for r in rows], dtype=torch.float64)
    torch.testing.assert_close(f, want_f, rtol=1e-4, atol=1e-7)
    torch.testing.assert_close(pdf, want_pdf, rtol=1e-4, atol=1e-7)
