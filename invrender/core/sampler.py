"""Counter-based random numbers (docs/architecture.md#counter-based-random-numbers).

Every uniform number is a pure function of ``(seed, pixel, sample, bounce, dimension)``: a 32-bit
integer hash (Wellons' ``lowbias32``, a strong avalanche mix) of those counters, mapped to [0, 1).
Nothing is stored between calls, so an image does not depend on chunk size or device, and path
replay can regenerate a path's numbers instead of keeping them.

**Pixel patterns.** :func:`multijitter` places a pixel's N film samples by correlated multi-jittered
sampling (Kensler, "Correlated Multi-Jittered Sampling", Pixar technical memo 13-01, 2013) for any
N, not only squares: a pure function of (pattern, sample, N) too.

**Antithetic pairs.** The lowest bit of a path key is not hashed: it marks a *mirrored* path, whose
every number is ``1 - u`` (exactly: the bit complement of the 24 bits, so still in [0, 1)) for the
``u`` its partner (the same key with the bit clear) draws. :func:`path_keys` returns keys with the bit
clear; :func:`mirrored` sets it.

The hash is written once (:func:`invrender.core.lanes.lowbias32`) and runs compiled by Dr.Jit or
on int32 tensors, where products wrap modulo 2^32 (two's complement) and the logical right shifts
of unsigned arithmetic are an arithmetic shift followed by a mask. (int32 is several times faster
than int64 on the CPU, where 64-bit multiplies do not vectorize.)
"""

from __future__ import annotations

import functools
import math

import torch

from invrender.backends.arrays import TORCH
from invrender.core import compiled, lanes

_MASK = 0xFFFFFFFF


def _signed(x: int) -> int:
    """A 32-bit unsigned value as the int32 with the same bits."""
    x &= _MASK
    return x - (1 << 32) if x >= 1 << 31 else x


def _mix(x: torch.Tensor) -> torch.Tensor:
    """lowbias32 on an int32 tensor (bits read as unsigned): :func:`invrender.core.lanes.lowbias32`
    evaluated by torch."""
    return lanes.lowbias32(TORCH, x)


def _mix_int(x: int) -> int:
    """lowbias32 on a Python int (for constants folded outside the tensors); unsigned result."""
    x &= _MASK
    x ^= x >> 16
    x = (x * 0x7FEB352D) & _MASK
    x ^= x >> 15
    x = (x * 0x846CA68B) & _MASK
    return x ^ (x >> 16)


def _low32(x: torch.Tensor) -> torch.Tensor:
    """The low 32 bits of an int64 tensor, as int32: torch's integer conversion keeps them (it
    wraps, as C's does; ``tests/sampling`` holds it to the bitwise form), in one pass."""
    return x.to(torch.int32)


def seed_salt(seed: int) -> int:
    """The unsigned 32-bit word a render's seed contributes to every path key (:func:`path_keys`)."""
    return _mix_int(seed ^ 0x9E3779B9)


def path_keys(seed: int, pixel: torch.Tensor, sample: torch.Tensor) -> torch.Tensor:
    """One 32-bit key per path from its counters.

    Args:
        seed: the render's seed (any non-negative int; its low 32 bits count).
        pixel: (N,) int64 flat pixel index (row * width + column), < 2^32.
        sample: (N,) int64 sample index within the pixel, < 2^32.
    Returns:
        (N,) int32 keys (bits read as unsigned), the lowest bit clear (not mirrored).
    """
    return lanes.path_key(TORCH, _signed(seed_salt(seed)), _low32(pixel), _low32(sample))


def mirrored(keys: torch.Tensor, mirror: torch.Tensor | bool = True) -> torch.Tensor:
    """``keys`` (N,) marked as mirrored where ``mirror`` (N,) bool (or everywhere): their paths draw
    ``1 - u`` for every number ``u`` of the unmarked key."""
    bit = mirror.to(keys.dtype) if isinstance(mirror, torch.Tensor) else int(bool(mirror))
    return (keys & -2) | bit


def uniform(keys: torch.Tensor, bounce: int, dims: int) -> torch.Tensor:
    """Uniform numbers in [0, 1) for each path at one bounce.

    Args:
        keys: (N,) int32 path keys from :func:`path_keys`.
        bounce: vertex index (0 = the camera's sample).
        dims: how many numbers per path.
    Returns:
        (N, dims) float32, each the hash of (key, bounce, dimension): its low 24 bits / 2^24 (their
        complement for mirrored keys).
    """
    salts = tuple(compiled.Opaque(x) for x in bounce_salt_values(bounce, dims))
    return torch.stack(compiled.run(lanes.uniforms, keys.device, keys, salts), dim=1)


@functools.lru_cache(maxsize=4096)
def bounce_salt_values(bounce: int, dims: int) -> tuple[int, ...]:
    """The unsigned 32-bit salts of one bounce's ``dims`` dimensions (:func:`bounce_salts`)."""
    return tuple(_mix_int(bounce * 0x10000 + d + 0x632BE5AB) for d in range(dims))


@functools.lru_cache(maxsize=4096)
def bounce_salts(bounce: int, dims: int, device: torch.device) -> torch.Tensor:
    """(dims,) int32 salts of one bounce's dimensions on ``device``, made once: a tensor built from
    a list is a copy from pageable host memory, which on CUDA waits for the stream each bounce.
    Read only (never written in place). Kernels that draw a bounce's numbers themselves take these
    (:func:`uniform` is ``lowbias32((key & ~1) ^ salt_j)``: :func:`invrender.core.lanes.uniform`)."""
    return torch.tensor([_signed(x) for x in bounce_salt_values(bounce, dims)], dtype=torch.int32, device=device)


def branch_keys(keys: torch.Tensor, branch: int) -> torch.Tensor:
    """Keys (N,) for branch ``branch`` of paths that split (Whitted's reflection and refraction):
    independent of the parent's and of the other branches' numbers (mirrored if the parent is)."""
    return mirrored(_mix((keys & -2) ^ _signed(_mix_int(0xB5297A4D + branch))), (keys & 1) == 1)


_U32 = 0xFFFFFFFF


def _permuted(i: torch.Tensor, n: torch.Tensor, pattern: torch.Tensor) -> torch.Tensor:
    """Element ``i`` of a pseudo-random permutation of ``0 .. n - 1`` chosen by ``pattern``
    (:func:`invrender.core.lanes.permuted`, Kensler's hash with cycle walking, evaluated by torch).

    Args:
        i: (N,) int64 in ``[0, n)``.
        n: (N,) int64 permutation lengths >= 1 (< 2^32).
        pattern: (N,) int64 unsigned 32-bit pattern numbers.
    Returns:
        (N,) int64 in ``[0, n)``; for fixed (n, pattern) distinct i give distinct values.
    """
    return lanes.permuted(TORCH, _low32(i), _low32(n), _low32(pattern)).to(torch.int64) & _U32


def _columns(count: torch.Tensor) -> torch.Tensor:
    """(N,) int64: the largest divisor of each count that is at most its square root."""
    top = int(count.max())
    table = torch.ones(top + 1, dtype=torch.int64)
    for d in range(2, math.isqrt(top) + 1):
        table[d * d :: d] = d  # d increases, so the last write is the largest divisor <= sqrt(n)
    return table.to(count.device)[count]


def multijitter(pattern: torch.Tensor, sample: torch.Tensor, count: torch.Tensor | int, jitter: torch.Tensor) -> torch.Tensor:
    """Film positions in the unit pixel of ``count`` correlated multi-jittered samples.

    The count is factored as m x r (m the largest divisor at most sqrt(count): 4 x 4 for 16,
    4 x 8 for 32, 1 x 7 for 7) and the samples, their indices permuted, fill the cells of the
    m x r grid; inside its cell a sample sits in the sub-column and sub-row that two more
    permutations give, so that the projections on both axes are stratified into count strata as
    well (the "multi-jitter" of Chiu, Shirley and Wang 1994), and its ``jitter`` places it within
    that sub-cell. Every count is stratified on both axes, and in 2-D as finely as its factors
    allow (a prime count is a Latin hypercube); one sample is uniform over the pixel. Each
    sample's position is uniform over the pixel (averaged over patterns), so estimates stay
    unbiased. (A grid of ceil(count / m) rows with a partly empty last row would lose the 1-D
    strata: on the Cornell box's axis-aligned light edges 32 samples then did worse than 24.)

    Args:
        pattern: (N,) int64 unsigned 32-bit: which pattern (one per pixel and pass).
        sample: (N,) int64 index of the sample in its pattern, ``0 <= sample < count``.
        count: samples in the pattern, an int or (N,) int64 tensor >= 1.
        jitter: (N, 2) float32 uniforms in [0, 1).
    Returns:
        (N, 2) float32 positions in [0, 1)^2.
    """
    count = torch.as_tensor(count, dtype=torch.int64, device=sample.device).expand_as(sample)
    m = _columns(count) if count.numel() else count
    x, y = lanes.multijitter(TORCH, _low32(pattern), _low32(sample), _low32(count), _low32(m), jitter.unbind(1))
    return torch.stack([x, y], dim=1)
