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
MODES = {"stratified": 0, "independent": 1, "antithetic": 2, "stratified_direct": 3}
#: the bounce index of the first vertex's numbers (0 is the camera's)
FIRST_VERTEX = 1


def lane_samples(xp, pixel, sample, first, cells, m, width, key_salt, pattern_salt, salts, pinhole, strata, mode: int, lens: bool):
    """The camera samples of N paths (and a pinhole camera's ray directions).

    Args:
        pixel, sample: UInt the path's pixel (in the sampled grid, ``width`` pixels a row) and its
            sample's index in the pixel's pass, ``first`` (UInt or scalar) the pass's first index.
        cells, m: the pixel's pattern of ``cells`` samples (antithetic: pairs) factored ``m`` by
            ``cells / m`` (:func:`invrender.core.sampler.multijitter`); scalars or UInt.
        key_salt, pattern_salt: the hashed seeds of the path keys and of the pixel patterns;
            salts: those of the camera's numbers (bounce 0: film x, film y, lens u, lens v).
        pinhole: None, or a pinhole camera's (right, up, forward) 3-tuples, (tx, ty, 2 ox, 2 oy,
            width, height, border) scalars (:func:`pinhole_constants`).
        strata: None, or per pair of :data:`~invrender.core.lanes.DIRECT_PAIRS` the hashed seed of its patterns and the
            salts of its two dimensions at the first vertex, ``(pattern salt, salt, salt)``.
        mode: :data:`MODES`; lens: with the lens uniforms.
    Returns:
        keys UInt, film positions (2 Floats, in pixels), with ``lens`` the lens uniforms (2 Floats),
        with ``pinhole`` the rays' unit directions (3 Floats), with ``strata`` the first vertex's
        numbers of those dimensions (4 Floats): the pixel's samples multi-jittered per pair as
        its film positions are, by a pattern of the pair's own, each placed in its sub-cell by the
        number the vertex would otherwise draw.
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
    out = (keys, film)
    if lens:
        out += ((lanes.uniform(xp, keys, salts[2]), lanes.uniform(xp, keys, salts[3])),)
    if pinhole is not None:
        out += (pinhole_directions(xp, film, *pinhole),)
    if strata is not None:
        pairs = [lanes.multijitter(xp, lanes.path_key(xp, p, pixel, first), cell, cells, m, (lanes.uniform(xp, keys, a), lanes.uniform(xp, keys, b))) for p, a, b in strata]
        out += (tuple(u for pair in pairs for u in pair),)
    return out


def pinhole_directions(xp, film, right, up, forward, constants):
    """Unit directions (3 Floats) of a pinhole camera's rays through film positions ``film`` (2
    Floats, in the sampled grid's pixels): the expressions of
    :meth:`~invrender.scene.camera.Camera.generate_rays`, lane by lane."""
    tx, ty, ox2, oy2, width, height, border = constants
    x, y = film[0] - border, film[1] - border
    sx = (2.0 * x / width + ox2 - 1.0) * tx
    sy = (1.0 - 2.0 * y / height - oy2) * ty
    return lanes.normalize(xp, lanes.add(lanes.add(lanes.scale(right, sx), lanes.scale(up, sy)), forward))


def pinhole_constants(camera, width: int, height: int, border: int) -> tuple:
    """What :func:`pinhole_directions` reads of a pinhole ``camera`` with a ``width x height``
    image and a sampled border of ``border`` pixels, as opaque scalars (one kernel for every view):
    the frame's vectors rounded to float32 and twice the principal point offset, as the torch
    expressions take them."""
    right, up, forward = (tuple(Opaque(float(c)) for c in v.to(torch.float32)) for v in camera.frame())
    tx, ty = camera.tan_half_fov(width, height)
    ox, oy = camera.principal_point_offset
    return right, up, forward, tuple(Opaque(float(v)) for v in (tx, ty, 2.0 * ox, 2.0 * oy, width, height, border))


def direct_strata(seed: int) -> tuple:
    """:func:`lane_samples`' ``strata`` of a render's ``seed``: per pair of :data:`~invrender.core.lanes.DIRECT_PAIRS`, a
    pattern seed of its own (distinct from the film positions' and the other pair's, so the
    pixel's permutations of its samples are independent) and the salts of its two dimensions."""
    salts = bounce_salt_values(FIRST_VERTEX, 1 + max(lanes.DIRECT_DIMS))
    return tuple((Opaque(seed_salt(seed ^ (0x5EED + 0x9E37 * (k + 1)))), Opaque(salts[a]), Opaque(salts[b])) for k, (a, b) in enumerate(lanes.DIRECT_PAIRS))


def camera_samples(ids: torch.Tensor, spp: int, width: int, sampler: str, seed: int, lens: bool, plan=None, pinhole=None):
    """The camera samples of path ids ``ids`` (N,) int64: :func:`lane_samples` run by
    :func:`invrender.core.compiled.run`.

    Args:
        spp: samples per pixel (without a ``plan``: ids are ``pixel * spp + sample``);
        width: pixels a row of the sampled grid; sampler: ``RenderSettings.sampler``; seed: the
            render's; lens: draw lens uniforms; plan: a ``Plan`` (each pixel's count and first index);
            pinhole: :func:`pinhole_constants`, or None.
    Returns:
        pixel (N,) int64, keys (N,) int32, film positions (N, 2) float32 in pixels, lens uniforms
        (N, 2) float32 (None without ``lens``), and with ``pinhole`` the rays' unit directions (N,
        3) float32 (stored by columns); with the sampler ``"stratified_direct"``, last, the first
        vertex's numbers of :data:`~invrender.core.lanes.DIRECT_PAIRS` (N, 4) float32 (stored by columns).
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
    strata = direct_strata(seed) if sampler == "stratified_direct" else None
    out = compiled.run(lane_samples, ids.device, _low32(pixel), _low32(sample), first, cells, m, Opaque(width), key_salt, pattern_salt, salts, pinhole, strata, mode=MODES[sampler], lens=lens)
    samples = (pixel, out[0], out[1], out[2] if lens else None)
    if pinhole is not None:
        samples += (out[3 if lens else 2],)
    return samples if strata is None else samples + (out[-1],)
