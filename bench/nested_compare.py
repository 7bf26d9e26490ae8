"""Pointwise agreement of invrender's ``blendbsdf``, ``mask`` and ``pplastic`` with Mitsuba 3's:
``eval`` (three channels) and ``pdf`` on random direction pairs in the shading frame (normal +z),
the camera side ``wi`` over the upper hemisphere (materials Mitsuba makes one-sided) or the whole
sphere (those that transmit or are wrapped in ``twosided``), the light side likewise (SETTINGS);
then the mean sample weight (directional albedo) of 10^6 samples, Mitsuba's and invrender's.

Reported per setting: the largest relative error over entries whose Mitsuba value exceeds 1e-3,
the largest absolute error, the fraction of nonzero entries. ``--dump PATH`` writes the first
``--keep`` pairs of each setting with Mitsuba's values (JSON), the table
tests/plugins/test_nested_materials.py reads.

    python bench/nested_compare.py [--n 10000] [--dump PATH] [--keep 60]

Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402
from principled_compare import invrender_values, mitsuba_values  # noqa: E402

import invrender  # noqa: E402,F401  (registers the materials)
from invrender.plugins.bsdfs import checks  # noqa: E402
from invrender.scene.materials import Material  # noqa: E402

RP = {"type": "roughplastic", "diffuse_reflectance": {"type": "rgb", "value": [0.8, 0.35, 0.1]}, "alpha": 0.2}
RC = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "specular_reflectance": {"type": "rgb", "value": [0.7, 0.8, 0.9]}}
#: (name, Mitsuba dict, invrender type, its entries, where the directions lie: "sphere" both over the
#: whole sphere, "upper" the camera side above the surface, "above" both above: Mitsuba's
#: roughplastic has a nonzero pdf for light directions below its surface (where its eval is 0, and
#: which invrender's gives 0: a sample there is invalid in both), so its blends are compared above)
SETTINGS = [
    ("blend_rough", {"type": "blendbsdf", "weight": 0.3, "a": RP, "b": RC}, "blendbsdf(roughplastic,glossy)",
     {"weight": 0.3, "bsdf_0.reflectance": [0.8, 0.35, 0.1], "bsdf_0.roughness": 0.2, "bsdf_1.specular_reflectance": [0.7, 0.8, 0.9], "bsdf_1.roughness": 0.3}, "above"),
    ("blend_glass", {"type": "blendbsdf", "weight": 0.6, "a": {"type": "roughdielectric", "alpha": 0.3, "int_ior": 1.33},
                     "b": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.6, 0.4]}}}},
     "blendbsdf(roughdielectric,diffuse)", {"weight": 0.6, "bsdf_0.roughness": 0.3, "bsdf_0.int_ior": 1.33, "bsdf_1.reflectance": [0.2, 0.6, 0.4]}, "sphere"),
    ("mask_glossy", {"type": "mask", "opacity": 0.7, "bsdf": {"type": "twosided", "bsdf": {"type": "roughconductor", "alpha": 0.25}}},
     "mask(glossy_beckmann)", {"opacity": 0.7, "bsdf.roughness": 0.25}, "sphere"),
    ("mask_blend", {"type": "mask", "opacity": 0.4, "bsdf": {"type": "blendbsdf", "weight": 0.5, "a": RP, "b": {"type": "diffuse"}}},
     "mask(blendbsdf(roughplastic,diffuse))", {"opacity": 0.4, "bsdf.weight": 0.5, "bsdf.bsdf_0.reflectance": [0.8, 0.35, 0.1], "bsdf.bsdf_0.roughness": 0.2}, "above"),
    ("pplastic", {"type": "pplastic", "diffuse_reflectance": {"type": "rgb", "value": [0.3, 0.5, 0.2]}, "alpha": 0.15}, "pplastic",
     {"reflectance": [0.3, 0.5, 0.2], "roughness": 0.15}, "upper"),
    ("pplastic_ggx", {"type": "pplastic", "distribution": "ggx", "alpha": 0.4, "int_ior": 1.6, "specular_reflectance": {"type": "rgb", "value": [0.8, 0.7, 0.6]},
                      "diffuse_reflectance": {"type": "rgb", "value": [0.1, 0.25, 0.7]}}, "pplastic_ggx",
     {"reflectance": [0.1, 0.25, 0.7], "specular_reflectance": [0.8, 0.7, 0.6], "roughness": 0.4, "int_ior": 1.6}, "upper"),
]


def invrender_bsdf(type_name: str, entries: dict):
    """The material as a scene builds it (its constants resolved: the sampling weights)."""
    m = Material.of(type_name, "bench", **entries)
    return checks.instance(m.spec, **m.values, **m.constants)


def directions(n: int, seed: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(camera side, light side) (n, 3) each, unit, over the sphere or above (``where``: SETTINGS)."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    if where != "sphere":
        v[0, :, 2] = np.abs(v[0, :, 2])
    if where == "above":
        v[1, :, 2] = np.abs(v[1, :, 2])
    return v[0], v[1]


def errors(ours: np.ndarray, ref: np.ndarray, floor: float = 1e-3) -> tuple[float, float]:
    big = np.abs(ref) > floor
    rel = float(np.max(np.abs(ours - ref)[big] / np.abs(ref)[big])) if big.any() else 0.0
    return rel, float(np.max(np.abs(ours - ref)))


def mean_weights(mi_bsdf, bsdf, theta: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean sample weight (3,) and its standard error, Mitsuba's and invrender's, at ``wo`` theta."""
    import drjit as dr
    import mitsuba as mi

    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(math.sin(theta), 0.0, math.cos(theta))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(1, n)
    _, w = mi_bsdf.sample(mi.BSDFContext(), si, sampler.next_1d(), sampler.next_2d())
    theirs = np.stack([np.asarray(w[i]).astype(np.float64) for i in range(3)], 1)
    g = torch.Generator().manual_seed(1)
    ours = bsdf.sample(checks.shading_point(theta, n), torch.rand(n, generator=g), torch.rand(n, 2, generator=g)).weight.double().numpy()
    se = np.sqrt(theirs.var(0) / n + ours.var(0) / n)
    return theirs.mean(0), ours.mean(0), se


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--dump", type=Path, default=None)
    ap.add_argument("--keep", type=int, default=60)
    ap.add_argument("--samples", type=int, default=1_000_000)
    args = ap.parse_args()
    if not mitsuba_ref.available():
        print("Mitsuba 3 is not available (bench/README.md)", file=sys.stderr)
        return 2
    import mitsuba as mi

    print(f"{mitsuba_ref.label()}: eval and pdf on {args.n} direction pairs per setting")
    print(f"{'setting':<12} {'eval rel':>10} {'eval abs':>10} {'pdf rel':>10} {'pdf abs':>10} {'nonzero':>8}")
    table, worst = [], 0.0
    for k, (name, mi_dict, type_name, entries, where) in enumerate(SETTINGS):
        wi, wo = directions(args.n, k, where)
        mi_bsdf = mi.load_dict(mi_dict)
        f_m, p_m = mitsuba_values(mi_bsdf, wi, wo)
        bsdf = invrender_bsdf(type_name, entries)
        f_i, p_i = invrender_values(bsdf, wi, wo)
        (fr, fa), (pr, pa) = errors(f_i, f_m), errors(p_i, p_m)
        worst = max(worst, fr, pr)
        print(f"{name:<12} {fr:10.2e} {fa:10.2e} {pr:10.2e} {pa:10.2e} {float(np.mean(f_m.max(1) > 0)):8.3f}")
        for i in range(args.keep):
            table.append([name, np.round(wi[i], 7).tolist(), np.round(wo[i], 7).tolist(), [float(np.float32(x)) for x in f_m[i]], float(np.float32(p_m[i]))])
    print(f"worst relative error: {worst:.2e} (target 1e-4 where float32 allows)")
    print(f"\nmean sample weight of {args.samples} samples at theta 0.3 and 1.2 (Mitsuba, invrender, difference / s.e.)")
    for name, mi_dict, type_name, entries, where in SETTINGS:
        for theta in (0.3, 1.2):
            theirs, ours, se = mean_weights(mi.load_dict(mi_dict), invrender_bsdf(type_name, entries), theta, args.samples)
            print(f"  {name:<12} {theta:3.1f}  {np.round(theirs, 4).tolist()}  {np.round(ours, 4).tolist()}  z {np.round((ours - theirs) / se.clip(1e-12), 1).tolist()}")
    if args.dump:
        args.dump.write_text(json.dumps({"mitsuba": mitsuba_ref.label(), "settings": {s[0]: {"type": s[2], "entries": s[3]} for s in SETTINGS}, "pairs": table}, indent=0))
        print(f"wrote {len(table)} pairs to {args.dump}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
