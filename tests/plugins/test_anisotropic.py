"""Anisotropic microfacet materials (Mitsuba's ``alpha_u``/``alpha_v`` on ``roughconductor`` and
``roughdielectric``) against Mitsuba 3.9.1's own ``eval`` and ``pdf``, their sampling against their
pdf, and the UV tangent frame they are evaluated in (:mod:`invrender.core.shading`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.core.bsdfs import ShadingPoint
from invrender.core.frame import Frame
from invrender.core import shading
from invrender.plugins.bsdfs import checks
from invrender.plugins.bsdfs.glossy import Glossy, GlossyBeckmann
from invrender.plugins.bsdfs.metal_iors import METAL_IORS
from invrender.plugins.bsdfs.roughdielectric import RoughDielectric, RoughDielectricGGX

#: (plugin, distribution, side of wo, wo (Mitsuba's si.wi, local), wi (its wo: sampled by Mitsuba),
#: Mitsuba's eval (f cos, RGB) and pdf): ``mi.load_dict`` of a roughconductor (alpha_u 0.1,
#: alpha_v 0.35, material Au) and a roughdielectric (alpha_u 0.3, alpha_v 0.12, int_ior 1.5, ext_ior
#: 1), llvm_ad_rgb, shading frame the identity, the directions rounded to 6 digits first
MITSUBA = [
    ('roughconductor', 'ggx', 1, [[0.003034, 0.736797, 0.676107], [-0.632398, -0.322856, 0.704156], [0.042088, 0.937864, 0.34444], [-0.715365, 0.564755, 0.411466], [0.112517, -0.993159, 0.031223], [0.439768, -0.850195, 0.289435]], [[0.739522, 0.64788, 0.182644], [0.367097, -0.793048, 0.48612], [-0.037602, -0.62002, 0.783684], [0.727911, -0.398016, 0.558326], [0.14599, -0.987705, 0.055912], [-0.484434, -0.024422, 0.874487]], [[0.00477068, 0.003957461, 0.001605857], [0.06185754, 0.05130665, 0.02098043], [2.245242, 1.867687, 0.8203918], [3.291334, 2.753242, 1.277335], [0.03389964, 0.028125, 0.01136633], [0.4593302, 0.3810482, 0.1589084]], [0.006527253, 0.06894924, 2.373621, 3.487625, 0.1274492, 0.4761182]),
    ('roughdielectric', 'ggx', 1, [[-0.674043, -0.027146, 0.738193], [-0.965626, -0.184822, 0.182774], [0.051894, -0.996729, 0.061949], [0.608989, -0.69339, 0.385153], [0.056723, -0.304861, 0.950706], [0.535677, -0.842798, 0.052366]], [[0.407636, 0.050921, -0.911723], [0.750969, -0.079493, -0.655535], [-0.00292, 0.718953, -0.695052], [-0.563528, 0.482481, -0.670558], [-0.101938, 0.103724, -0.989368], [-0.566609, 0.655084, -0.499819]], [[6.990986, 6.990986, 6.990986], [0.0769184, 0.0769184, 0.0769184], [2.378749, 2.378749, 2.378749], [3.957544, 3.957544, 3.957544], [0.5794826, 0.5794826, 0.5794826], [1.385071, 1.385071, 1.385071]], [15.80033, 0.1780428, 5.372725, 9.059854, 1.304199, 3.222202]),
    ('roughdielectric', 'ggx', -1, [[-0.972928, -0.226173, -0.047507], [0.854809, 0.468816, -0.222515], [-0.2322, -0.157621, -0.959812], [-0.676982, -0.480313, -0.557669], [-0.106141, -0.173387, -0.979117], [-0.009234, -0.35552, -0.934623]], [[0.543308, 0.415283, -0.729628], [-0.812266, -0.443856, -0.378438], [-0.941752, -0.083418, -0.3258], [0.583091, 0.720511, -0.375324], [0.300672, 0.301391, 0.904852], [-0.007662, 0.555467, 0.831503]], [[0.3258899, 0.3258899, 0.3258899], [5.207821, 5.207821, 5.207821], [0.00218766, 0.00218766, 0.00218766], [0.1277762, 0.1277762, 0.1277762], [10.7516, 10.7516, 10.7516], [37.06314, 37.06314, 37.06314]], [0.3302762, 5.722562, 0.002542044, 0.1358946, 4.792231, 16.49896]),
    ('roughconductor', 'beckmann', 1, [[0.876216, -0.31352, 0.365993], [0.518957, 0.384091, 0.763647], [-0.074838, 0.033351, 0.996638], [0.196503, -0.648829, 0.735124], [0.306898, 0.142197, 0.94106], [-0.051593, -0.868985, 0.492142]], [[-0.81075, 0.3346, 0.480341], [-0.546592, -0.772673, 0.32282], [0.208986, 0.590389, 0.779594], [-0.206725, 0.978252, 0.016954], [-0.316359, -0.686429, 0.654777], [-0.048429, 0.701513, 0.711009]], [[3.307628, 2.787645, 1.362552], [1.193925, 0.9935114, 0.4383317], [0.5807063, 0.4817624, 0.1949182], [0.1392727, 0.1176185, 0.05820566], [1.121924, 0.9305816, 0.3796727], [2.006507, 1.667765, 0.7246796]], [3.442797, 1.25107, 0.6007502, 0.9010167, 1.161035, 2.081283]),
    ('roughdielectric', 'beckmann', 1, [[-0.486963, -0.384313, 0.784328], [0.789226, -0.096741, 0.606435], [0.01736, -0.904729, 0.425634], [-0.830772, 0.011803, 0.556487], [-0.184539, -0.848226, 0.496446], [0.797882, -0.323789, 0.508473]], [[0.313571, 0.256627, -0.91423], [-0.516545, 0.044953, -0.855079], [0.022009, 0.615069, -0.788166], [0.650864, 0.042461, -0.758005], [0.178973, 0.526975, -0.830823], [-0.634251, 0.267724, -0.725292]], [[21.609, 21.609, 21.609], [12.80264, 12.80264, 12.80264], [10.60216, 10.60216, 10.60216], [4.880005, 4.880005, 4.880005], [5.954013, 5.954013, 5.954013], [4.585829, 4.585829, 4.585829]], [48.62024, 28.80593, 23.85485, 10.98001, 13.39653, 10.31811]),
    ('roughdielectric', 'beckmann', -1, [[0.550411, -0.063764, -0.832456], [-0.588053, 0.72943, -0.349464], [-0.127647, 0.01873, -0.991643], [0.706763, 0.39736, -0.585312], [-0.714078, 0.490632, -0.499373], [-0.146374, 0.563701, -0.812906]], [[-0.782767, 0.017775, -0.622061], [0.379817, -0.670571, -0.637239], [0.485385, 0.245432, -0.839145], [-0.812173, -0.549094, 0.19715], [0.332111, -0.410319, -0.849318], [0.308418, -0.784294, 0.538296]], [[1.965923, 1.965923, 1.965923], [3.308628, 3.308628, 3.308628], [0.01601784, 0.01601784, 0.01601784], [4.772723, 4.772723, 4.772723], [1.666967, 1.666967, 1.666967], [11.09123, 11.09123, 11.09123]], [1.965925, 3.308625, 0.01601785, 2.255068, 1.666967, 4.929434]),
]

TYPES = {("roughconductor", "ggx"): Glossy, ("roughconductor", "beckmann"): GlossyBeckmann, ("roughdielectric", "ggx"): RoughDielectricGGX, ("roughdielectric", "beckmann"): RoughDielectric}


def _material(plugin: str, distribution: str):
    cls = TYPES[plugin, distribution]
    if plugin == "roughconductor":
        eta, k = METAL_IORS["Au"]
        return checks.instance(cls, roughness=0.1, alpha_v=0.35, eta=tuple(eta), k=tuple(k))
    return checks.instance(cls, roughness=0.3, alpha_v=0.12, int_ior=1.5, ext_ior=1.0)


def _point(wo: torch.Tensor, side: float) -> ShadingPoint:
    """Points whose shading frame is Mitsuba's identity frame turned to ``wo``'s side (x, y kept)."""
    n = wo.shape[0]
    z = torch.tensor([0.0, 0.0, side]).expand(n, 3).clone()
    zeros = torch.zeros(n, dtype=torch.int64)
    sp = ShadingPoint(wo, z, z, torch.full((n,), side > 0), torch.zeros(n, 2), zeros, zeros)
    sp.__dict__["frame"] = Frame(torch.tensor([1.0, 0.0, 0.0]).expand(n, 3), torch.tensor([0.0, 1.0, 0.0]).expand(n, 3), z)
    return sp


@pytest.mark.parametrize("case", MITSUBA, ids=[f"{c[0]}-{c[1]}-{'out' if c[2] > 0 else 'in'}" for c in MITSUBA])
def test_eval_and_pdf_are_mitsubas(case):
    plugin, distribution, side, wo, wi, f_mi, pdf_mi = case
    bsdf = _material(plugin, distribution)
    assert bsdf.lane_form().tangent  # evaluated in the UV tangent frame
    sp = _point(torch.tensor(wo), float(side))
    wi = torch.tensor(wi)
    f, pdf = bsdf.eval(sp, wi), bsdf.pdf(sp, wi)
    assert f.reshape(-1).tolist() == pytest.approx(np.ravel(f_mi).tolist(), rel=2e-4, abs=1e-7)
    assert pdf.tolist() == pytest.approx(pdf_mi, rel=2e-4, abs=1e-7)


@pytest.mark.parametrize("cls", [Glossy, GlossyBeckmann, RoughDielectric, RoughDielectricGGX])
@pytest.mark.parametrize("front", [True, False])
def test_anisotropic_sampling_follows_its_pdf(cls, front):
    bsdf = checks.instance(cls, roughness=0.15, alpha_v=0.5)
    for theta in (0.3, 1.2):
        assert checks.chi_square_p(bsdf, theta, samples=100_000, front=front) > 1e-3, theta
        e_pdf, e_weight, _ = checks.weight_errors(bsdf, theta, front=front)
        # 5e-3: float32 rounding of the weight 1e-4 of a wi grazing at z ~ 1e-5 (Beckmann, theta 1.2)
        assert e_pdf < 2e-3 and e_weight < 5e-3, (theta, e_pdf, e_weight)


def test_isotropic_materials_keep_their_frame_and_form():
    """alpha_v 0 (the default) is the isotropic form: no tangent frame, the same lane functions."""
    for cls in TYPES.values():
        form = checks.instance(cls).lane_form()
        assert not form.tangent and ("alpha_v", 1) not in form.keys
