"""Adaptive sampling: a pilot pass, per-pixel variance estimates, then more samples where the
estimated error is high, in rounds whose sample counts are fixed before they are traced.

The estimate stays unbiased (docs/sampling.md#adaptive-sampling): the pilot only allocates, and
the image is the fixed-weight mean ``(1/R) sum_r X_r`` of R rounds, round r's pixel estimate
``X_r`` being the mean of ``n_r`` samples whose count was chosen from earlier passes only. Given
that count, ``X_r`` is an unbiased mean of independent samples (their random numbers are those of
sample indices no earlier pass used), so ``E[X_r] = I`` and, by linearity, the mean of the rounds
is unbiased too. Averaging all samples with their counts as weights would not be: a pixel whose
first samples happened to be bright gets more samples, which dilute exactly those bright ones.

Allocation minimises the sum over pixels of the squared relative error
``sigma_p^2 / (n_p d_p^2)``, ``d_p = mu_p + floor * mean(mu)``, for a round's budget: Neyman's
``n_p`` proportional to ``sigma_p / d_p``, between 1 and a cap, and with a target error no more
than the pixel needs to reach it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch

from invrender.errors import ParameterError
from invrender.scene.scene import Scene
from invrender.core.driver import RenderSettings, SamplePlan, check_film_memory, check_filter_supported, cpu_workers, for_each_chunk
from invrender.validate import MAX_SPP, check_int
from invrender.core.film import Film


@dataclass(frozen=True)
class AdaptiveSettings:
    """Adaptive sampling (``render(..., adaptive=...)``); the budget is the render's ``spp``, the
    average number of samples per pixel, pilot included.

    Attributes:
        pilot_spp: samples per pixel of the pilot pass, which only allocates (its samples are not in
            the image); >= 2. None = an eighth of the budget, at least 4 and at most 16.
        rounds: passes after the pilot, each allocated from every sample traced before it and each
            given an equal part of the budget and an equal weight in the image; >= 1.
        target_error: relative standard error per pixel at which a pixel gets no more samples than
            it needs (> 0); None = spend the whole budget. With a target the budget is a cap.
        max_spp: most samples one pixel gets, pilot included; None = 16 x the budget.
        floor: errors are relative to ``mu_p + floor * mean(mu)`` (mu: pixel means), so that
            dark pixels do not take the whole budget; >= 0 (0 = purely relative).
    """

    pilot_spp: int | None = None
    rounds: int = 2
    target_error: float | None = None
    max_spp: int | None = None
    floor: float = 1.0

    def __post_init__(self):
        owner = "adaptive "
        if self.pilot_spp is not None:
            check_int(owner, "pilot_spp", self.pilot_spp, 2, MAX_SPP)
        check_int(owner, "rounds", self.rounds, 1, 1000)
        if self.target_error is not None and not (_is_number(self.target_error) and math.isfinite(self.target_error) and self.target_error > 0):
            raise ParameterError(f"adaptive target_error must be a number > 0, got {self.target_error!r}")
        if self.max_spp is not None:
            check_int(owner, "max_spp", self.max_spp, 1, MAX_SPP)
        if not (_is_number(self.floor) and math.isfinite(self.floor) and self.floor >= 0):
            raise ParameterError(f"adaptive floor must be a number >= 0, got {self.floor!r}")

    @staticmethod
    def make(value) -> AdaptiveSettings | None:
        """From ``render``'s ``adaptive=``: None/False (off), True (defaults), a dict of fields, or
        an :class:`AdaptiveSettings`."""
        if value is None or value is False:
            return None
        if value is True:
            return AdaptiveSettings()
        if isinstance(value, AdaptiveSettings):
            return value
        if isinstance(value, dict):
            known = {f.name for f in dataclasses.fields(AdaptiveSettings)}
            unknown = sorted(set(value) - known)
            if unknown:
                raise ParameterError(f"adaptive has no setting {unknown[0]!r} (its settings: {', '.join(sorted(known))})")
            return AdaptiveSettings(**value)
        raise ParameterError(f"adaptive must be True, a dict of settings or an AdaptiveSettings, got {value!r}")

    def pilot(self, spp: int) -> int:
        """Pilot samples per pixel for a budget of ``spp``."""
        return self.pilot_spp if self.pilot_spp is not None else min(max(4, spp // 8), 16)

    def check_budget(self, spp: int) -> None:
        """A one-line error unless ``spp`` pays for the pilot and one sample per pixel and round."""
        need = self.pilot(spp) + self.rounds
        if spp < need:
            raise ParameterError(f"adaptive sampling needs spp >= pilot_spp + rounds = {need} (one sample per pixel and round after the pilot), got spp={spp}")
        cap = self.max_spp if self.max_spp is not None else 16 * spp
        if cap < need:
            raise ParameterError(f"adaptive max_spp must be >= pilot_spp + rounds = {need}, got {cap}")


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


@dataclass(frozen=True)
class AdaptiveResult:
    """An adaptively sampled image and how it was sampled.

    Attributes:
        image: (H, W, 3) float32 linear radiance (differentiable as ``render``'s image is).
        spp: (H, W) int64 samples traced per pixel, pilot included.
        error: (H, W) float32 estimated relative standard error of each pixel (relative to
            ``mu + floor * mean(mu)``, as the allocation measures it).
        passes: the rounds' :class:`~invrender.core.driver.SamplePlan`\\ s (pilot excluded),
            each weighted ``1 / len(passes)`` in the image.
        pilot_spp: samples per pixel of the pilot.
    """

    image: torch.Tensor
    spp: torch.Tensor
    error: torch.Tensor
    passes: tuple[SamplePlan, ...]
    pilot_spp: int


@dataclass
class PixelMoments:
    """Running per-pixel sample moments of the path radiance's channel mean y (float64, detached).

    Attributes:
        n: (P,) samples so far.
        sum_y: (P,) sum of y.
        sum_y2: (P,) sum of y^2.
    """

    n: torch.Tensor
    sum_y: torch.Tensor
    sum_y2: torch.Tensor

    @staticmethod
    def zeros(pixels: int, device) -> PixelMoments:
        z = torch.zeros(pixels, dtype=torch.float64, device=device)
        return PixelMoments(z.clone(), z.clone(), z.clone())

    def add(self, count: torch.Tensor, sum_y: torch.Tensor, sum_y2: torch.Tensor) -> None:
        self.n += count.to(self.n)
        self.sum_y += sum_y
        self.sum_y2 += sum_y2

    @property
    def mean(self) -> torch.Tensor:
        """(P,) sample mean."""
        return self.sum_y / self.n.clamp_min(1)

    @property
    def variance(self) -> torch.Tensor:
        """(P,) unbiased sample variance of one sample (0 with fewer than 2)."""
        mu = self.mean
        return ((self.sum_y2 - self.n * mu * mu) / (self.n - 1).clamp_min(1)).clamp_min(0)


@dataclass(frozen=True)
class PassSums:
    """What one pass traced, per pixel.

    Attributes:
        radiance: (P, 3) float64 sum of the paths' radiance (differentiable when autograd records).
        sum_y, sum_y2: (P,) float64 sums of each path's channel-mean radiance y and of y^2 (detached).
    """

    radiance: torch.Tensor
    sum_y: torch.Tensor
    sum_y2: torch.Tensor


def trace_pass(integrator, ctx, scene: Scene, settings: RenderSettings, device: torch.device) -> PassSums:
    """Trace the samples of ``settings.plan`` (or ``settings.spp`` per pixel) with ``integrator``
    in the prepared context ``ctx``, keeping each path's total radiance apart for the moments."""
    pixels = scene.width * scene.height
    workers = cpu_workers(device)
    radiance = [torch.zeros(pixels, 3, dtype=torch.float64, device=device) for _ in range(workers)]
    sum_y = [torch.zeros(pixels, dtype=torch.float64, device=device) for _ in range(workers)]
    sum_y2 = [torch.zeros(pixels, dtype=torch.float64, device=device) for _ in range(workers)]

    def work(worker: int, state) -> None:
        n = state.count
        film = Film(n, 1, False, device)  # one film entry per path (branches add into their path)
        integrator.trace(ctx, state.replace(pixel=torch.arange(n, device=device)), film)
        L = film.sums()  # (n, 3) each path's radiance
        y = L.detach().mean(dim=1)
        radiance[worker].index_add_(0, state.pixel, L)
        sum_y[worker].index_add_(0, state.pixel, y)
        sum_y2[worker].index_add_(0, state.pixel, y * y)

    for_each_chunk(scene, settings, device, work)
    return PassSums(sum(radiance), sum(sum_y), sum(sum_y2))


def allocate(share: torch.Tensor, upper: torch.Tensor, budget: int) -> torch.Tensor:
    """Integer sample counts (P,) int64 in ``[1, upper]`` proportional to ``share`` (P,) >= 0
    where the bounds allow (``n = clip(c share, 1, upper)``, c found by bisection), summing to
    ``budget``, or to ``sum(upper)`` when that is less (every pixel then gets its upper bound)."""
    upper = upper.to(torch.float64).clamp_min(1)
    if float(upper.sum()) <= budget:
        return upper.long()
    if not bool((share > 0).any()):
        share = torch.ones_like(share)
    share = share.to(torch.float64)
    lo, hi = 0.0, float(upper.max()) / float(share[share > 0].min())
    for _ in range(100):  # sum(clip(c share, 1, upper)) is non-decreasing in c
        c = 0.5 * (lo + hi)
        if float(torch.minimum(torch.clamp_min(c * share, 1.0), upper).sum()) < budget:
            lo = c
        else:
            hi = c
    x = torch.minimum(torch.clamp_min(hi * share, 1.0), upper)
    return _round_to_total(x, upper.long(), budget)


def _round_to_total(x: torch.Tensor, upper: torch.Tensor, total: int) -> torch.Tensor:
    """Largest-remainder rounding of ``x`` (P,) to integers <= ``upper`` summing to ``total``
    (as far as the bounds allow); deterministic."""
    n = x.floor().long()
    missing = total - int(n.sum())
    if missing > 0:
        frac = torch.where(n < upper, x - n, -1.0)
        order = torch.argsort(frac, descending=True, stable=True)[: min(missing, int((n < upper).sum()))]
        n[order] += 1
    elif missing < 0:
        frac = torch.where(n > 1, x - n, 2.0)
        order = torch.argsort(frac, stable=True)[: min(-missing, int((n > 1).sum()))]
        n[order] -= 1
    return n


def round_counts(moments: PixelMoments, adaptive: AdaptiveSettings, budget: int, cap: int, shape: tuple[int, int]) -> torch.Tensor:
    """Sample counts (P,) int64 of the next round from the moments of every earlier sample.

    ``share = sigma / d`` (relative standard deviation of one sample), raised to the largest of
    its 3 x 3 neighbourhood (``shape`` = (H, W)): a pixel only partly covered by an object may
    show no variance in a small pilot, its neighbour does. Bounded by ``cap`` per pixel and, with a
    target error, by ``(share / target)^2 / rounds``: the round's part of the samples that bring
    the final estimate to the target."""
    mu = moments.mean
    d = (mu + adaptive.floor * mu.mean()).clamp_min(1e-30)
    share = torch.nn.functional.max_pool2d((moments.variance.sqrt() / d).reshape(1, 1, *shape), 3, stride=1, padding=1).reshape(-1)
    upper = torch.full_like(share, float(cap))
    if adaptive.target_error is not None:
        need = (share / adaptive.target_error) ** 2 / adaptive.rounds
        upper = torch.minimum(upper, need.ceil())
    return allocate(share, upper, budget)


def adaptive_render(integrator, scene: Scene, settings: RenderSettings, adaptive: AdaptiveSettings, device: torch.device, params: dict | None = None) -> AdaptiveResult:
    """Render ``scene`` with ``settings.spp`` samples per pixel on average, allocated adaptively.

    Records autograd where a parameter requires grad (the allocation itself is detached, as every
    sampling decision is). ``params`` overrides ``scene.params`` values.
    """
    check_filter_supported(scene, "adaptive sampling")
    if settings.terms:
        raise ParameterError("adaptive sampling gives the full image only: terms=True is not available with adaptive")
    if settings.plan is not None:
        raise ParameterError("adaptive sampling makes its own sample plans")
    adaptive.check_budget(settings.spp)
    check_film_memory(scene.width, scene.height, device, 2)
    pixels, rounds = scene.width * scene.height, adaptive.rounds
    pilot_spp = adaptive.pilot(settings.spp)
    cap = max(1, ((adaptive.max_spp if adaptive.max_spp is not None else 16 * settings.spp) - pilot_spp) // rounds)
    ctx = integrator.context(scene, settings, device, params)
    moments = PixelMoments.zeros(pixels, device)

    pilot = SamplePlan(torch.full((pixels,), pilot_spp, dtype=torch.int64, device=device), torch.zeros(pixels, dtype=torch.int64, device=device))
    with torch.no_grad():  # the pilot only allocates
        sums = trace_pass(integrator, ctx, scene, settings.replace(plan=pilot), device)
    moments.add(pilot.count, sums.sum_y, sums.sum_y2)

    remaining = pixels * (settings.spp - pilot_spp)  # samples left for the rounds
    first = pilot.count.clone()
    image, passes, inv_counts = 0.0, [], torch.zeros(pixels, dtype=torch.float64, device=device)
    for r in range(rounds):
        count = round_counts(moments, adaptive, remaining // (rounds - r), cap, (scene.height, scene.width))
        plan = SamplePlan(count, first.clone())
        sums = trace_pass(integrator, ctx, scene, settings.replace(plan=plan), device)
        image = image + sums.radiance / (rounds * count[:, None].to(torch.float64))  # (1/R) X_r
        moments.add(count, sums.sum_y, sums.sum_y2)
        inv_counts += 1.0 / count.to(torch.float64)
        passes.append(plan)
        first += count
        remaining -= int(count.sum())

    # Var(image_p) = sum_r sigma_p^2 / (R^2 n_r,p), relative to mu_p + floor * mean(mu)
    mu = moments.mean
    d = (mu + adaptive.floor * mu.mean()).clamp_min(1e-30)
    error = (moments.variance * inv_counts).sqrt() / (rounds * d)
    shape = (scene.height, scene.width)
    return AdaptiveResult(image.float().reshape(*shape, 3), first.reshape(shape), error.float().reshape(shape), tuple(passes), pilot_spp)
