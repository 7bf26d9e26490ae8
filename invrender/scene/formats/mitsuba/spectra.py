"""Spectra as Mitsuba 3's RGB variants turn them into linear sRGB triples.

A spectrum is a list of (wavelength in nm, value) pairs, in increasing wavelength: written inline
in a Mitsuba file (``<spectrum value="400:0.1, 500:0.5"/>``), or read from an ``.spd`` file (two
columns, ``#`` comments: :func:`read_spd`). :func:`spectrum_to_srgb` integrates it against the
CIE 1931 colour matching functions as Mitsuba's ``spectrum_list_to_srgb`` does:

- 1000 wavelengths evenly spaced over [360, 830] nm (both ends included), those outside the
  spectrum's range skipped, the spectrum interpolated linearly at each;
- with ``d65``, each value weighted by the CIE D65 illuminant (Mitsuba's normalized table), as
  Mitsuba does for reflectances and other colours outside emitters;
- XYZ = the sum of the colour matching functions times the (weighted) value, times
  ``(830 - 360) / 1000 / 106.7502593994140625`` (the normalization of Y);
- linear sRGB = the XYZ -> sRGB matrix (Rec. 709 primaries, D65 white) times XYZ; clamped to
  [0, 1] when ``bounded`` (reflectances), else negative channels to 0.

Mitsuba 3.9.1's XML reader (RGB variants) converts a ``<spectrum>`` property with ``bounded`` and
``d65`` both true for reflectance-like colours, ``bounded`` false and ``d65`` true for ``eta``,
``k``, ``int_ior`` and ``ext_ior``, and both false inside an ``<emitter>`` (radiance,
irradiance: no D65 weighting); its named conductors' tables (``complex_ior_from_file``) use both
false. A flat reflectance of 0.5 so becomes 0.4977, 0.4999, 0.4975; a flat radiance of 0.5 becomes
0.5998, 0.4748, 0.4517 (the white of a flat spectrum is not D65's).

Data: :data:`CIE_TABLE`, the CIE 1931 2-degree colour matching functions and the D65 illuminant
at 5 nm from 360 to 830 nm, as Mitsuba 3 tabulates them (include/mitsuba/core/spectrum.h: the CIE's
published values, D65 scaled by Mitsuba's normalization), read from the mitsuba 3.9.1 wheel at
the table's nodes (``mi.cie1931_xyz``, ``mi.cie_d65``); between nodes they are interpolated
linearly, as Mitsuba does.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

CIE_MIN, CIE_MAX, CIE_STEP = 360.0, 830.0, 5.0
#: the steps of the integration over [CIE_MIN, CIE_MAX] (Mitsuba's MI_CIE_SAMPLES)
STEPS = 1000
#: 1 / the integral of the Y matching function (Mitsuba's MI_CIE_Y_NORMALIZATION)
Y_NORMALIZATION = 1.0 / 106.7502593994140625
XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535], [-0.969256, 1.875991, 0.041556], [0.055648, -0.204043, 1.057311]])

#: x-bar, y-bar, z-bar and D65 at CIE_MIN, CIE_MIN + 5, ..., CIE_MAX nm (95 rows; see the module docstring)
CIE_TABLE = np.array([
    (0.0001299, 3.91699996e-06, 0.000606100017, 0.471106261),
    (0.000232100007, 6.96500001e-06, 0.001086, 0.498636246),
    (0.000414899987, 1.23899999e-05, 0.00194600003, 0.52616626),
    (0.000741600001, 2.202e-05, 0.003486, 0.515491247),
    (0.00136800006, 3.89999987e-05, 0.00645000115, 0.504816175),
    (0.00223600003, 6.39999998e-05, 0.0105499905, 0.528415799),
    (0.00424299994, 0.000119999997, 0.0200500097, 0.552016437),
    (0.00765000004, 0.000216999993, 0.0362100005, 0.693972647),
    (0.0143100005, 0.000395999989, 0.0678500086, 0.835929871),
    (0.0231899992, 0.000639999984, 0.110200003, 0.880026996),
    (0.0435100012, 0.00121000002, 0.207399994, 0.924125135),
    (0.0776299983, 0.00218000007, 0.371300012, 0.93395263),
    (0.134379998, 0.00400000019, 0.645600021, 0.943780184),
    (0.214770004, 0.00730000017, 1.0390501, 0.90969038),
    (0.283899993, 0.0115999999, 1.38559997, 0.87560159),
    (0.328500003, 0.0168399997, 1.62295997, 0.9674353),
    (0.348280013, 0.023, 1.74705994, 1.05927002),
    (0.348060012, 0.0297999997, 1.78260005, 1.12059486),
    (0.336199999, 0.0379999988, 1.77210999, 1.18192983),
    (0.318699986, 0.0480000004, 1.74409997, 1.18599057),
    (0.290800005, 0.0599999987, 1.66919994, 1.1900512),
    (0.251100004, 0.0738999993, 1.52810001, 1.17514181),
    (0.195360005, 0.0909800008, 1.28763998, 1.16024244),
    (0.142100006, 0.112599999, 1.04190004, 1.16560614),
    (0.0956400037, 0.139019996, 0.812950075, 1.17096996),
    (0.0579500087, 0.169300005, 0.61619997, 1.13504982),
    (0.0320100002, 0.208020002, 0.46518001, 1.09912968),
    (0.0147000002, 0.258599997, 0.353300005, 1.1018672),
    (0.00490000006, 0.323000014, 0.272000015, 1.10461462),
    (0.00240000011, 0.407299995, 0.212300003, 1.09677613),
    (0.00930000003, 0.503000021, 0.158199996, 1.08893752),
    (0.0291000009, 0.608200014, 0.111699998, 1.07372499),
    (0.0632700026, 0.709999979, 0.0782499909, 1.05851245),
    (0.1096, 0.793200016, 0.0572500117, 1.0731492),
    (0.1655, 0.861999989, 0.0421600007, 1.08779609),
    (0.225749895, 0.914850116, 0.02984, 1.07120979),
    (0.290399998, 0.953999996, 0.0203000009, 1.05462348),
    (0.359699994, 0.980300009, 0.0133999996, 1.05280519),
    (0.433449894, 0.994950116, 0.00874999911, 1.05099714),
    (0.512050092, 1, 0.00574999908, 1.03056228),
    (0.594500005, 0.995000005, 0.00389999989, 1.01012731),
    (0.67839998, 0.978600025, 0.00274999905, 0.991612732),
    (0.762099981, 0.952000022, 0.00209999993, 0.973098099),
    (0.842499971, 0.915400028, 0.00179999997, 0.970339417),
    (0.916299999, 0.870000005, 0.00165000104, 0.967580795),
    (0.978600025, 0.816299975, 0.00139999995, 0.93170917),
    (1.02629995, 0.757000029, 0.00109999999, 0.895837545),
    (1.05669999, 0.694899976, 0.00100000005, 0.902507424),
    (1.06219995, 0.630999982, 0.00079999998, 0.909177303),
    (1.04560006, 0.566799998, 0.000600000028, 0.907120585),
    (1.00259995, 0.503000021, 0.000339999999, 0.905065),
    (0.938399971, 0.441199988, 0.000239999994, 0.895466805),
    (0.854449928, 0.381000012, 0.000190000006, 0.885868549),
    (0.751399994, 0.32100001, 9.99999975e-05, 0.863594234),
    (0.642400026, 0.264999986, 4.99999915e-05, 0.841320932),
    (0.541899979, 0.216999993, 2.99999992e-05, 0.843394697),
    (0.447899997, 0.174999997, 1.99999995e-05, 0.845468581),
    (0.360799998, 0.1382, 9.99999975e-06, 0.826920569),
    (0.283499986, 0.107000001, 0, 0.808372617),
    (0.218700007, 0.0816000029, 0, 0.809321105),
    (0.164900005, 0.0610000007, 0, 0.810269594),
    (0.121200003, 0.0445800014, 0, 0.820690095),
    (0.0873999968, 0.0320000015, 0, 0.831110597),
    (0.0636000037, 0.0231999997, 0, 0.810940325),
    (0.046769999, 0.0170000009, 0, 0.790770173),
    (0.0329000019, 0.0119200004, 0, 0.74752152),
    (0.0227000006, 0.00820999965, 0, 0.704273939),
    (0.0158399995, 0.00572300004, 0, 0.713808537),
    (0.0113591598, 0.00410200004, 0, 0.723343134),
    (0.00811091624, 0.00292899995, 0, 0.737180829),
    (0.00579034584, 0.00209100009, 0, 0.751019597),
    (0.00410945714, 0.00148400001, 0, 0.686649263),
    (0.00289932708, 0.00104700006, 0, 0.622278869),
    (0.00204918999, 0.000739999989, 0, 0.66410619),
    (0.00143997103, 0.000520000001, 0, 0.705933571),
    (0.00099994929, 0.000361100014, 0, 0.732203901),
    (0.000690078596, 0.000249200006, 0, 0.75847429),
    (0.000476021291, 0.000171899999, 0, 0.70042026),
    (0.000332301104, 0.000119999997, 0, 0.642367303),
    (0.000234826104, 8.47999981e-05, 0, 0.555624604),
    (0.000166150494, 5.99999985e-05, 0, 0.468882948),
    (0.000117413001, 4.23999991e-05, 0, 0.571851313),
    (8.30752688e-05, 2.99999992e-05, 0, 0.674819589),
    (5.87065188e-05, 2.11999995e-05, 0, 0.657533348),
    (4.15099385e-05, 1.49899997e-05, 0, 0.640247047),
    (2.93532594e-05, 1.05999998e-05, 0, 0.644899666),
    (2.06738296e-05, 7.46570004e-06, 0, 0.649552286),
    (1.45597696e-05, 5.25779978e-06, 0, 0.625045598),
    (1.02539798e-05, 3.7028999e-06, 0, 0.600539923),
    (7.22145614e-06, 2.60780007e-06, 0, 0.562695503),
    (5.085868e-06, 1.83659995e-06, 0, 0.524852097),
    (3.58165198e-06, 1.29340003e-06, 0, 0.55253762),
    (2.52252494e-06, 9.10929998e-07, 0, 0.580223262),
    (1.77650895e-06, 6.41529994e-07, 0, 0.594727635),
    (1.25114104e-06, 4.51809996e-07, 0, 0.609233081),
]
)  # fmt: skip

_NODES = CIE_MIN + CIE_STEP * np.arange(len(CIE_TABLE))


def cie1931_xyz(wavelengths: np.ndarray) -> np.ndarray:
    """The CIE 1931 matching functions (n, 3) at ``wavelengths`` (n,) nm, linear between the
    table's nodes, 0 outside [360, 830]."""
    w = np.asarray(wavelengths, dtype=np.float64)
    return np.stack([np.interp(w, _NODES, CIE_TABLE[:, i], left=0.0, right=0.0) for i in range(3)], axis=1)


def cie_d65(wavelengths: np.ndarray) -> np.ndarray:
    """Mitsuba's normalized D65 illuminant (n,) at ``wavelengths`` (n,) nm, 0 outside [360, 830]."""
    return np.interp(np.asarray(wavelengths, dtype=np.float64), _NODES, CIE_TABLE[:, 3], left=0.0, right=0.0)


def spectrum_to_srgb(wavelengths, values, bounded: bool = True, d65: bool = False) -> np.ndarray:
    """Linear sRGB (3,) float64 of a tabulated spectrum, as Mitsuba's ``spectrum_list_to_srgb``
    (see the module docstring); ``wavelengths`` (n,) nm increasing, ``values`` (n,)."""
    wl = np.asarray(wavelengths, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    w = CIE_MIN + np.arange(STEPS) / (STEPS - 1) * (CIE_MAX - CIE_MIN)
    w = w[(w >= wl[0]) & (w <= wl[-1])]
    s = np.interp(w, wl, v)
    if d65:
        s = s * cie_d65(w)
    xyz = (cie1931_xyz(w) * s[:, None]).sum(0) * (CIE_MAX - CIE_MIN) * Y_NORMALIZATION / STEPS
    rgb = XYZ_TO_SRGB @ xyz
    return np.clip(rgb, 0.0, 1.0) if bounded else np.maximum(rgb, 0.0)


class SpectrumError(ValueError):
    """A malformed spectrum (the message says what; the caller names the file and line)."""


def parse_pairs(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Wavelengths and values of Mitsuba's inline ``"w1:v1, w2:v2, ..."``; SpectrumError when a
    token is not a ``wavelength:value`` pair of numbers or the wavelengths decrease."""
    pairs = []
    for token in (t for t in re.split(r"[,\s]+", text.strip()) if t):
        parts = token.split(":")
        if len(parts) != 2:
            raise SpectrumError(f"expected wavelength:value pairs, got {_short(token)}")
        try:
            pairs.append((float(parts[0]), float(parts[1])))
        except ValueError:
            raise SpectrumError(f"could not parse the wavelength:value pair {_short(token)}") from None
    return _checked(pairs)


def read_spd(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Wavelengths and values of an ``.spd`` file (two numbers a line, ``#`` comments);
    SpectrumError naming the line when one is not two numbers or the wavelengths decrease."""
    pairs = []
    for i, line in enumerate(Path(path).read_text(errors="replace").splitlines(), 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        try:
            if len(fields) != 2:
                raise ValueError
            pairs.append((float(fields[0]), float(fields[1])))
        except ValueError:
            raise SpectrumError(f"line {i} of {path} is not two numbers (wavelength value): {_short(line.strip())}") from None
    return _checked(pairs, f" in {path}")


def _checked(pairs: list, where: str = "") -> tuple[np.ndarray, np.ndarray]:
    if not pairs:
        raise SpectrumError(f"the spectrum has no wavelength:value pairs{where}")
    data = np.asarray(pairs, dtype=np.float64)
    if not np.all(np.isfinite(data)):
        raise SpectrumError(f"spectrum values must be finite{where}")
    if np.any(np.diff(data[:, 0]) < 0):
        raise SpectrumError(f"wavelengths must not decrease{where}")
    return data[:, 0], data[:, 1]


def _short(text: str) -> str:
    return repr(text if len(text) <= 40 else text[:37] + "...")
