"""The camera's samples of a chunk of paths, written once against the array interface.

A path id (``pixel * spp + sample``, or a plan's) becomes its path key, its film position and, for
a thin lens, its lens uniforms (:func:`invrender.core.driver.camera_paths` documents the
samplers): :func:`lane_samples` computes them per lane against the array interface
(:mod:`invrender.backends.arrays`), from the counter-based hash of :mod:`invrender.core.lanes`
(path keys, uniforms, multi-jittered patterns), and :func:`camera_samples` evaluates it with
:func:`invrender.core.compiled.run`: one kernel compiled by Dr.Jit where it loads, eager torch
otherwise (the same bits either way). The 64-bit ids are split into pixel and sample by torch;
the hash reads their low 32 bits.
"""

from __future__ import annotations

import math

import torch

from invrender.core import compiled, lanes
from invrender.core.compiled import Opaque
from invrender.core.sampler import _columns, _low32, bounce_salt_values, seed_salt

#: the samplers' codes in :func:`lane_samples` (``RenderSettings.sampler``)
MODES = {"stratified": 0, "independent": 1, "antithetic": 2}


def lane_samples(xp, pixel, sample, first, cells, m, width, key_salt, pattern_salt, salts, mode: int, lens: bool):
    """The camera samples of N paths.

    Args:
        pixel, sample: UInt the path's pixel (in the sampled grid, ``width`` pixels a row) and its
            sample's index in the pixel's pass, ``first`` (UInt or scalar) the pass's first index.
        cells, m: the pixel's pattern of ``cells`` samples (antithetic: pairs) factored ``m`` by
            ``cells / m`` (:func:`invrender.core.sampler.multijitter`); scalars or UInt.
        key_salt, pattern_salt: the hashed seeds of the path keys and of the pixel patterns;
            salts: those of the camera's numbers (bounce 0: film x, film y, lens u, lens v).
        mode: :data:`MODES`; lens: with the lens uniforms.
    Returns:
        keys UInt, film positions (2 Floats, in pixels), and with ``lens`` the lens uniforms (2 Floats).
    """
    if mode == MODES["antithetic"]:  # pairs share their counters, the second mirrored
        cell = xp.shr(sample, 1)
        keys = lanes.path_key(xp, key_salt, pixel, first + cell * 2) | (sample & 1)
    else:
        cell = sample
        keys = lanes.path_key(xp, key_salt, pixel, first + sample)
    fx, fy = lanes.uniform(xp, keys, salts[0]), lanes.uniform(xp, keys, salts[1])
    if mode != MODES["independent"]:  # one pattern per pixel and pass
        pattern = lanes.path_key(xp, pattern_salt, pixel, first)
        fx, fy = lanes.multijitter(xp, pattern, cell, cells, m, (fx, fy))
    film = (xp.float(xp.umod(pixel, width)) + fx, xp.float(xp.udiv(pixel, width)) + fy)
    if not lens:
        return keys, film
    return keys, film, (lanes.uniform(xp, keys, salts[2]), lanes.uniform(xp, keys, salts[3]))


def camera_samples(ids: torch.Tensor, spp: int, width: int, sampler: str, seed: int, lens: bool, plan=None):
    """The camera samples of path ids ``ids`` (N,) int64: :func:`lane_samples` run by
    :func:`invrender.core.compiled.run`.

    Args:
        spp: samples per pixel (without a ``plan``: ids are ``pixel * spp + sample``);
        width: pixels a row of the sampled grid; sampler: ``RenderSettings.sampler``; seed: the
            render's; lens: draw lens uniforms; plan: a ``Plan`` (each pixel's count and first index).
    Returns:
        pixel (N,) int64, keys (N,) int32, film positions (N, 2) float32 in pixels, lens uniforms
        (N, 2) float32 (None without ``lens``).
    """
    if plan is None:
        pixel = ids // spp
        sample = ids - pixel * spp
        cells = (spp + 1) // 2 if sampler == "antithetic" else spp
        m = max(d for d in range(1, math.isqrt(cells) + 1) if cells % d == 0)  # sampler.multijitter's factors
        first, cells, m = Opaque(0), Opaque(cells), Opaque(m)
    else:
        pixel, sample = plan.locate(ids)
        count, first = plan.count.to(ids.device)[pixel], plan.first.to(ids.device)[pixel]
        cells = (count + 1) // 2 if sampler == "antithetic" else count
        m = _columns(cells) if cells.numel() else cells
        first, cells, m = _low32(first), _low32(cells), _low32(m)
    salts = tuple(Opaque(s) for s in bounce_salt_values(0, 4 if lens else 2))
    key_salt, pattern_salt = Opaque(seed_salt(seed)), Opaque(seed_salt(seed ^ 0x5EED))
    out = compiled.run(lane_samples, ids.device, _low32(pixel), _low32(sample), first, cells, m, Opaque(width), key_salt, pattern_salt, salts, mode=MODES[sampler], lens=lens)
    return pixel, out[0], out[1], out[2] if lens else None
