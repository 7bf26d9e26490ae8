"""Counter-based random numbers (DESIGN.md decision 3).

Every uniform number is a pure function of ``(seed, pixel, sample, bounce, dimension)``: a 32-bit
integer hash (Wellons' ``lowbias32``, a strong avalanche mix) of those counters, mapped to [0, 1).
Nothing is stored between calls, so an image does not depend on chunk size or device, and path
replay can regenerate a path's numbers instead of keeping them.

All integer work is done in int64 tensors masked to 32 bits (torch has no full uint32 arithmetic);
products wrap in two's complement, which leaves the low 32 bits exact.
"""

from __future__ import annotations

import torch

_MASK = 0xFFFFFFFF


def _mix(x: torch.Tensor) -> torch.Tensor:
    """lowbias32 on int64 tensors holding 32-bit values; same shape."""
    x = x ^ (x >> 16)
    x = (x * 0x7FEB352D) & _MASK
    x = x ^ (x >> 15)
    x = (x * 0x846CA68B) & _MASK
    return x ^ (x >> 16)


def _mix_int(x: int) -> int:
    """lowbias32 on a Python int (for constants folded outside the tensors)."""
    x &= _MASK
    x ^= x >> 16
    x = (x * 0x7FEB352D) & _MASK
    x ^= x >> 15
    x = (x * 0x846CA68B) & _MASK
    return x ^ (x >> 16)


def path_keys(seed: int, pixel: torch.Tensor, sample: torch.Tensor) -> torch.Tensor:
    """One 32-bit key per path from its counters.

    Args:
        seed: the render's seed.
        pixel: (N,) int64 flat pixel index (row * width + column).
        sample: (N,) int64 sample index within the pixel.
    Returns:
        (N,) int64 keys in [0, 2^32).
    """
    k = _mix((pixel & _MASK) ^ _mix_int(seed ^ 0x9E3779B9))
    k = _mix(k ^ (pixel >> 32))
    return _mix(k ^ (sample & _MASK))


def uniform(keys: torch.Tensor, bounce: int, dims: int) -> torch.Tensor:
    """Uniform numbers in [0, 1) for each path at one bounce.

    Args:
        keys: (N,) int64 path keys from :func:`path_keys`.
        bounce: vertex index (0 = the camera's sample).
        dims: how many numbers per path.
    Returns:
        (N, dims) float32, each the hash of (key, bounce, dimension), with 24 random bits.
    """
    salts = torch.tensor([_mix_int(bounce * 0x10000 + d + 0x632BE5AB) for d in range(dims)], dtype=torch.int64, device=keys.device)
    h = _mix(keys[:, None] ^ salts)
    return (h >> 8).to(torch.float32) * (1.0 / 16777216.0)
