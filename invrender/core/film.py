"""The film: accumulates path contributions per pixel, optionally one image per Neumann term."""

from __future__ import annotations

import torch

from invrender.core.ranks import max_across_ranks, sum_across_ranks, world


class Film:
    """Accumulation of radiance samples into pixels.

    With the box filter (``rfilter`` None or a box) each contribution lands in its own pixel
    (:meth:`add`) and the image is the sum over spp; with another filter each sample's radiance is
    splatted into every pixel its filter reaches (:meth:`splat`, from its film position) and each
    pixel is divided by the sum of the weights it received (:mod:`invrender.core.rfilter`).

    With ``terms`` each contribution is kept in the image of its Neumann term k (the contribution of
    paths with k reflections, ``g (Mg)^k eps``); otherwise everything goes to one image. Sums are
    kept in float64, so the float32 image does not depend on the order in which chunks arrive;
    each image is stored as three planes (3, W * H), one per channel, which torch adds into by
    index two to three times faster than (W * H, 3) rows (131k contributions on one core: 0.5-0.8
    ms against 1.2-1.3 ms, whether they come as rows or as columns).
    """

    #: replay's adjoint pass sets this: the integrator then carries the throughput beta detached
    detach_throughput = False
    #: may the fused bounce (:mod:`invrender.core.fused`) trace paths into this film, where it
    #: applies (False: the torch bounce traces them, as it traces path replay's adjoint pass)
    fused_bounce = True

    def __init__(self, width: int, height: int, terms: bool, device, rfilter=None):
        self.width, self.height, self.terms, self.device = width, height, terms, device
        self._images: dict[int, torch.Tensor] = {}
        self.rfilter = None if rfilter is None or rfilter.is_box else rfilter
        #: (W * H,) float64 sums of the filter weights each pixel received (None for the box)
        self.weights = None if self.rfilter is None else torch.zeros(width * height, dtype=torch.float64, device=device)

    def splat(self, xy: torch.Tensor, radiance: dict[int, torch.Tensor]) -> None:
        """Samples at film positions ``xy`` (N, 2) with radiance (N, 3) per Neumann term (a dict
        term -> tensor): each into every pixel its filter reaches, weighted (a film with a filter)."""
        terms = list(radiance)
        values = torch.cat([radiance[k].to(torch.float64) for k in terms] + [torch.ones(xy.shape[0], 1, dtype=torch.float64, device=xy.device)], dim=1)
        index, sums = self.rfilter.splat(xy, values, self.width, self.height)  # (M,), (M, 3 T + 1): each term's RGB, then the weight
        self.weights.index_add_(0, index, sums[:, -1])
        for t, term in enumerate(terms):
            self._plane(term if self.terms else 0).index_add_(1, index, sums[:, 3 * t : 3 * t + 3].t())

    def add(self, term: int, pixel: torch.Tensor, radiance: torch.Tensor) -> None:
        """Add ``radiance`` (N, 3) to the flat ``pixel`` indices (N,) of Neumann term ``term``."""
        self._plane(term if self.terms else 0).index_add_(1, pixel, radiance.t().double())

    def _plane(self, key: int) -> torch.Tensor:
        """(3, W * H) float64 the sums of image ``key`` (created at zero)."""
        if key not in self._images:
            self._images[key] = torch.zeros(3, self.width * self.height, dtype=torch.float64, device=self.device)
        return self._images[key]

    def visit(self, pixel: torch.Tensor, s) -> None:
        """Hook called when the paths writing to ``pixel`` (N,) reach new vertices ``s`` (a
        :class:`~invrender.core.surface.Surface` of N hits), before anything is added there.
        The film ignores it; path records note where each path met a textured parameter."""

    def arrive(self, pixel: torch.Tensor, d: torch.Tensor) -> None:
        """Hook called just before the next contribution of the paths writing to ``pixel`` (N,)
        that may end on an emitter infinitely far away (an escaped ray, an emitter sample): the
        radiance it carries arrives along world directions ``d`` (N, 3). The film ignores it; path
        records look up which texels of an environment map that radiance reads."""

    def scatter(self, pixel: torch.Tensor, weight: torch.Tensor) -> None:
        """Hook called at each scattering vertex with the sample weight ``f cos / pdf`` (N, 3) the
        path's throughput is multiplied by, after every contribution that does not pass through it
        was added. The film ignores it; path replay's adjoint film turns it into the gradient of
        everything the path gathers beyond the vertex."""

    def branch(self, pixel: torch.Tensor) -> torch.Tensor:
        """Film indices (M,) for new paths split off paths writing to ``pixel`` (M,) (Whitted's
        reflection and refraction): the same pixels here; path replay's films give each branch an
        index of its own."""
        return pixel

    def sums(self) -> torch.Tensor:
        """(W * H, 3) float64 sums of all contributions so far, all terms together."""
        total = torch.zeros(3, self.width * self.height, dtype=torch.float64, device=self.device)
        for img in self._images.values():
            total = total + img
        return total.t()

    @staticmethod
    def merge(films: list[Film]) -> Film:
        """One film holding the sums of ``films`` (same size and ``terms``)."""
        out = films[0]
        for other in films[1:]:
            for k, img in other._images.items():
                out._images[k] = out._images[k] + img if k in out._images else img
            if out.weights is not None:
                out.weights += other.weights
        return out

    def summed_across_ranks(self) -> Film:
        """This film holding every rank's contributions (all-reduced float64 sums, differentiable;
        itself outside a torch.distributed group): for renders whose chunks were split across ranks."""
        if world()[1] == 1:
            return self
        count = max_across_ranks(max(self._images, default=-1) + 1, self.device)
        for k in range(count):
            image = self._images.get(k)
            self._images[k] = sum_across_ranks(image if image is not None else torch.zeros(3, self.width * self.height, dtype=torch.float64, device=self.device))
        if self.weights is not None:
            self.weights = sum_across_ranks(self.weights)
        return self

    def develop(self, spp: int, terms: int = 1) -> torch.Tensor:
        """The mean over ``spp`` samples (box), or each pixel's weighted sum divided by its sum of
        weights (0 where it received none; another filter): (H, W, 3), or (K, H, W, 3) per term
        with ``terms``, K at least ``terms`` (the terms the integrator keeps: an image of zeros for
        terms nothing reached)."""
        shape = (self.height, self.width, 3)
        norm = spp if self.weights is None else self.weights.masked_fill(self.weights == 0, 1.0)[:, None]
        zero = torch.zeros(3, self.width * self.height, dtype=torch.float64, device=self.device)
        if not self.terms:
            return (self._images.get(0, zero).t() / norm).float().reshape(shape)
        count = max(max(self._images, default=-1) + 1, terms)
        return torch.stack([(self._images.get(k, zero).t() / norm).float().reshape(shape) for k in range(count)])


class PathFilm(Film):
    """A film with one entry per path (the film index is the path), growing when paths split;
    :meth:`totals` folds every branch's radiance into its parent's. Path replay's primal pass traces
    into one (each path's radiance is what its adjoint pass strikes off vertex by vertex), and so do
    the chunks of a render with a filter before their samples are splatted (per term with
    ``terms``; differentiable)."""

    def __init__(self, n: int, device, terms: bool = False):
        super().__init__(n, 1, terms, device)
        self.size = n
        self._branches: list[tuple[torch.Tensor, torch.Tensor]] = []  # (new indices, parent indices)

    def add(self, term: int, pixel: torch.Tensor, radiance: torch.Tensor) -> None:
        key = term if self.terms else 0
        if key not in self._images or self._images[key].shape[1] < self.size:
            grown = torch.zeros(3, self.size, dtype=torch.float64, device=self.device)
            if key in self._images:
                grown[:, : self._images[key].shape[1]] = self._images[key]
            self._images[key] = grown
        self._images[key].index_add_(1, pixel, radiance.t().double())

    def branch(self, pixel: torch.Tensor) -> torch.Tensor:
        new = torch.arange(self.size, self.size + pixel.numel(), device=pixel.device)
        self._branches.append((new, pixel))
        self.size += pixel.numel()
        return new

    def totals(self, term: int = 0) -> torch.Tensor:
        """(size, 3) float64: each path's radiance (of Neumann term ``term`` with ``terms``),
        including all its branches'."""
        total = torch.zeros(self.size, 3, dtype=torch.float64, device=self.device)
        if term in self._images:
            total[: self._images[term].shape[1]] = self._images[term].t()
        for new, parent in reversed(self._branches):  # children are created after their parents
            total.index_add_(0, parent, total[new])
        return total

    def term_totals(self) -> dict[int, torch.Tensor]:
        """Neumann term -> :meth:`totals` of that term (one entry, 0, without ``terms``)."""
        return {k: self.totals(k) for k in sorted(self._images)}

