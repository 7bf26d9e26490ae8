"""Counter-based random numbers (docs/architecture.md#counter-based-random-numbers).

Every uniform number is a pure function of ``(seed, pixel, sample, bounce, dimension)``: a 32-bit
integer hash (Wellons' ``lowbias32``, a strong avalanche mix) of those counters, mapped to [0, 1).
Nothing is stored between calls, so an image does not depend on chunk size or device, and path
replay can regenerate a path's numbers instead of keeping them.

**Antithetic pairs.** The lowest bit of a path key is not hashed: it marks a *mirrored* path, whose
every number is ``1 - u`` (exactly: the bit complement of the 24 bits, so still in [0, 1)) for the
``u`` its partner (the same key with the bit clear) draws. :func:`path_keys` returns keys with the bit
clear; :func:`mirrored` sets it.

The hash runs on int32 tensors: products wrap modulo 2^32 (two's complement), and the logical right
shifts of unsigned arithmetic are an arithmetic shift followed by a mask. (int32 is several times
faster than int64 on the CPU, where 64-bit multiplies do not vectorize.)
"""

from __future__ import annotations

import functools

import torch

from invrender.transport import kernels

_MASK = 0xFFFFFFFF


def _signed(x: int) -> int:
    """A 32-bit unsigned value as the int32 with the same bits."""
    x &= _MASK
    return x - (1 << 32) if x >= 1 << 31 else x


_M1 = _signed(0x7FEB352D)
_M2 = _signed(0x846CA68B)


def _mix(x: torch.Tensor) -> torch.Tensor:
    """lowbias32 on an int32 tensor (bits read as unsigned); a new tensor of the same shape.

    After the first step everything is done in place on the new tensor: each temporary of a
    wavefront is megabytes, and fresh ones cost their page faults (the hash is ~10% of a render).
    """
    x = x ^ ((x >> 16) & 0xFFFF)
    x.mul_(_M1)
    t = x >> 15
    x ^= t.bitwise_and_(0x1FFFF)
    x.mul_(_M2)
    t = x >> 16
    return x.bitwise_xor_(t.bitwise_and_(0xFFFF))


def _mix_int(x: int) -> int:
    """lowbias32 on a Python int (for constants folded outside the tensors); unsigned result."""
    x &= _MASK
    x ^= x >> 16
    x = (x * 0x7FEB352D) & _MASK
    x ^= x >> 15
    x = (x * 0x846CA68B) & _MASK
    return x ^ (x >> 16)


def _low32(x: torch.Tensor) -> torch.Tensor:
    """The low 32 bits of an int64 tensor, as int32."""
    y = x & _MASK
    return (y - ((y >> 31) << 32)).to(torch.int32)


def path_keys(seed: int, pixel: torch.Tensor, sample: torch.Tensor) -> torch.Tensor:
    """One 32-bit key per path from its counters.

    Args:
        seed: the render's seed (any non-negative int; its low 32 bits count).
        pixel: (N,) int64 flat pixel index (row * width + column), < 2^32.
        sample: (N,) int64 sample index within the pixel, < 2^32.
    Returns:
        (N,) int32 keys (bits read as unsigned), the lowest bit clear (not mirrored).
    """
    k = _mix(_low32(pixel) ^ _signed(_mix_int(seed ^ 0x9E3779B9)))
    return _mix(k ^ _low32(sample)) & -2


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
    salts = _salts(bounce, dims, keys.device)
    if kernels.enabled(keys.device):
        return kernels.hash_uniforms(keys, salts)
    h = _mix((keys & -2)[:, None] ^ salts)
    h ^= -(keys & 1)[:, None]  # mirrored: all bits flipped, so the low 24 give 1 - 2^-24 - u
    return h.bitwise_and_(0xFFFFFF).to(torch.float32).mul_(1.0 / 16777216.0)


@functools.lru_cache(maxsize=4096)
def _salts(bounce: int, dims: int, device: torch.device) -> torch.Tensor:
    """(dims,) int32 salts of one bounce's dimensions on ``device``, made once: a tensor built from
    a list is a copy from pageable host memory, which on CUDA waits for the stream each bounce.
    Read only (never written in place)."""
    return torch.tensor([_signed(_mix_int(bounce * 0x10000 + d + 0x632BE5AB)) for d in range(dims)], dtype=torch.int32, device=device)


def branch_keys(keys: torch.Tensor, branch: int) -> torch.Tensor:
    """Keys (N,) for branch ``branch`` of paths that split (Whitted's reflection and refraction):
    independent of the parent's and of the other branches' numbers (mirrored if the parent is)."""
    return mirrored(_mix((keys & -2) ^ _signed(_mix_int(0xB5297A4D + branch))), (keys & 1) == 1)
