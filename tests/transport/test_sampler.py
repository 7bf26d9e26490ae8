"""Counter-based random numbers: uniform, independent across counters, pure functions of them."""

import torch

from invrender.transport.sampler import path_keys, uniform


def numbers(n=200_000, seed=0, bounce=1, dims=6):
    ids = torch.arange(n)
    return uniform(path_keys(seed, ids // 16, ids % 16), bounce, dims)


def test_uniform_moments_and_histogram():
    u = numbers()
    assert u.min() >= 0 and u.max() < 1
    assert abs(u.mean().item() - 0.5) < 0.002
    assert abs(u.var().item() - 1 / 12) < 0.001
    counts = torch.histc(u[:, 0], bins=50, min=0, max=1)
    expected = u.shape[0] / 50
    chi2 = ((counts - expected) ** 2 / expected).sum().item()
    assert chi2 < 100  # 49 degrees of freedom: p < 1e-4 above this


def test_dimensions_bounces_seeds_uncorrelated():
    a = numbers()
    b = numbers(bounce=2)
    c = numbers(seed=1)
    for x, y in [(a[:, 0], a[:, 1]), (a[:, 0], b[:, 0]), (a[:, 0], c[:, 0]), (a[:-1, 0], a[1:, 0])]:
        r = torch.corrcoef(torch.stack([x, y]))[0, 1].item()
        assert abs(r) < 0.01


def test_pure_function_of_counters():
    ids = torch.arange(1000)
    keys = path_keys(7, ids // 10, ids % 10)
    sub = path_keys(7, ids[500:600] // 10, ids[500:600] % 10)
    assert torch.equal(uniform(keys, 3, 4)[500:600], uniform(sub, 3, 4))
