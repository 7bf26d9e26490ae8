"""Correlated multi-jittered pixel samples (sampler.multijitter): every count stratified.

The old grid stratified floor(sqrt(N))^2 of a pixel's N samples and drew the rest uniformly, so the
error of a pixel's estimate went up from 16 to 32 samples. These tests pin the properties that make
the error fall with every added sample: the permutations are permutations, every count fills
distinct cells and distinct strata on both axes, positions are uniform over the pixel on average
(an unbiased box filter), and the squared error of an edge's coverage falls monotonically in N.
"""

from __future__ import annotations

import math

import pytest
import torch

from invrender.core.sampler import _low32, _permuted, multijitter


def test_low32_keeps_the_low_bits_of_any_int64():
    """The counters' words are the low 32 bits of 64-bit ids (pattern seeds past 2^31, path ids
    past 2^32): torch's conversion must keep them, as the bitwise form does, on every value."""
    x = torch.cat([torch.tensor([0, 1, -1, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**40 + 12345, -(2**40) - 7, 2**63 - 1, -(2**63)]),
                   torch.randint(-(2**62), 2**62, (10000,), generator=torch.Generator().manual_seed(0))])  # fmt: skip
    y = x & 0xFFFFFFFF
    assert torch.equal(_low32(x), (y - ((y >> 31) << 32)).to(torch.int32))
    assert _low32(x)[:9].tolist() == [0, 1, -1, 2**31 - 1, -(2**31), -1, 0, 12345, -7]


@pytest.mark.parametrize("n", [1, 2, 3, 5, 16, 17, 100, 1000])
def test_permuted_is_a_permutation(n):
    for pattern in (0, 1, 12345, 2**31, 2**32 - 1):
        v = _permuted(torch.arange(n), torch.full((n,), n), torch.full((n,), pattern))
        assert sorted(v.tolist()) == list(range(n))


def test_patterns_differ():
    n = 64
    a = _permuted(torch.arange(n), torch.full((n,), n), torch.full((n,), 7))
    b = _permuted(torch.arange(n), torch.full((n,), n), torch.full((n,), 8))
    assert (a != b).sum() > n // 2


@pytest.mark.parametrize("count", list(range(1, 41)) + [48, 63, 64, 65, 96, 128])
def test_every_count_is_stratified(count):
    """N samples occupy the N cells of the m x r grid (m r = N, m the largest divisor <= sqrt(N)),
    and the N strata of width 1 / N on the x axis and on the y axis."""
    g = torch.Generator().manual_seed(count)
    m = max(d for d in range(1, math.isqrt(count) + 1) if count % d == 0)
    r = count // m
    for pattern in (3, 99991, 2**32 - 5):
        xy = multijitter(torch.full((count,), pattern), torch.arange(count), count, torch.rand(count, 2, generator=g))
        assert ((xy >= 0) & (xy < 1)).all()
        cells = (xy[:, 1] * r).long() * m + (xy[:, 0] * m).long()
        assert cells.unique().numel() == count
        assert (xy[:, 0] * count).long().unique().numel() == count
        assert (xy[:, 1] * count).long().unique().numel() == count


def test_positions_are_uniform_over_the_pixel():
    """Over many patterns each sample index is uniform over the pixel: a 4 x 4 histogram of sample
    5 of N (and of all N) is flat within 4 standard deviations."""
    patterns = torch.arange(20000, dtype=torch.int64) * 2654435761 % 2**32
    for count, k in ((12, 5), (12, None), (7, 5), (32, 5), (32, None)):  # 3 x 4, 1 x 7, 4 x 8
        if k is not None:
            k = torch.full((patterns.numel(),), k)
        if k is None:
            pat, s = patterns[:2000].repeat_interleave(count), torch.arange(count).repeat(2000)
        else:
            pat, s = patterns, k
        xy = multijitter(pat, s, count, torch.rand(s.numel(), 2, generator=torch.Generator().manual_seed(1)))
        h = torch.bincount((xy[:, 1] * 4).long() * 4 + (xy[:, 0] * 4).long(), minlength=16).double()
        expected = s.numel() / 16
        assert ((h - expected).abs() < 4 * math.sqrt(expected)).all(), h


@pytest.mark.parametrize("edge", [(1.0, 0.37), (1.0, 0.0), (0.0, 1.0)], ids=["slanted", "vertical", "horizontal"])
def test_edge_error_falls_with_every_count(edge):
    """The coverage of a pixel by an edge a x + b y < c (slanted, and axis-aligned as a light's are),
    c spread over the pixel: its mean squared error over 4000 pixels (patterns) falls at every step
    of 4, 8, 12, 16, 24, 32, 48, 64, 96, 128 samples (the old grid's rose from 16 to 32)."""
    a, b = edge
    c = 0.4 + 0.55 * torch.arange(4000, dtype=torch.float64) / 4000  # the edge's offset, one per pixel (inside it)

    def coverage_mse(count):
        patterns = torch.arange(4000, dtype=torch.int64) * 40503 % 2**32
        pat, s = patterns.repeat_interleave(count), torch.arange(count).repeat(patterns.numel())
        xy = multijitter(pat, s, count, torch.rand(s.numel(), 2, generator=torch.Generator().manual_seed(count)))
        inside = (a * xy[:, 0] + b * xy[:, 1] < c.repeat_interleave(count)).double().reshape(-1, count).mean(1)
        exact = c - b / 2 if a else c  # the area of the region over the unit square
        err = inside - exact
        assert abs(float(err.mean())) < 4 * float(err.std()) / math.sqrt(err.numel()) + 1e-9  # unbiased
        return float((err**2).mean())

    mse = [coverage_mse(n) for n in (4, 8, 12, 16, 24, 32, 48, 64, 96, 128)]
    assert all(a > b for a, b in zip(mse, mse[1:])), mse
    assert mse[-1] < mse[0] / 30  # faster than 1/N (32x the samples): stratification at work
