"""Path records: the traced Monte Carlo estimate as an explicit polynomial in the parameters.

Sampling never depends on a differentiable parameter (``docs/architecture.md``, detached sampling),
so once paths are traced every contribution a path adds to a pixel is a *monomial* in the
parameters, per colour channel:

    contribution_c = w_c * prod_p v_{p,c} ^ k_p

with ``w`` fixed by the sampling decisions (directions, pdfs, MIS weights, roulette survival) and
``k_p`` the number of times the parameter ``p`` is a factor: 1 for the emitter a contribution ends
on, and for a reflectance-like parameter the number of path vertices on its material (its BSDF
factor f is linear in it). Summed over paths, each pixel and channel of the image is a polynomial
with one coefficient per monomial. :func:`record_paths` traces once and keeps those coefficients;
:meth:`PathRecords.image` re-evaluates the image at any parameter values without tracing. Because
the pdfs are those of the record point, that image is an unbiased estimate of the true image at
the new values (not only at the record point), and its derivatives are exact derivatives of it.

How the exponents are found: the trace runs once under forward-mode automatic differentiation with
the tangent of parameter p set to ``v_p * R^(p)`` (mixed radix: ``R^(p)`` is the product of the
radices of the parameters before p, each radix one more than the parameter's largest possible
degree). A monomial's tangent is then ``contribution * sum_p k_p R^(p)``: dividing by the
contribution gives an integer code that spells out the exponents, digit by digit. No integrator
knows it is being recorded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.autograd.forward_ad as fwAD

from invrender.errors import ParameterError
from invrender.scene.kinds import kind_of
from invrender.scene.scene import Scene
from invrender.transport.driver import RenderSettings, for_each_chunk
from invrender.transport.film import Film
from invrender.transport.integrators import make_integrator

#: largest exponent code the float32 trace resolves exactly (its relative rounding stays < 1e-6)
MAX_CODES = 1 << 16


@dataclass(frozen=True)
class PathRecords:
    """A traced estimate as a polynomial in the recorded parameters.

    Attributes:
        names: the recorded parameters, each an RGB triple.
        exponents: (S, P) int64, the exponent of each parameter in each of the S monomials.
        coefficients: (S, H * W, 3) float64, per monomial the sum over a pixel's paths of their
            fixed weights w, divided by spp.
        resolution: (width, height).
        record_values: name -> (3,) the values the paths were traced at.
        spp: samples per pixel traced.
        seed: the seed of the traced paths.
    """

    names: tuple[str, ...]
    exponents: torch.Tensor
    coefficients: torch.Tensor
    resolution: tuple[int, int]
    record_values: dict
    spp: int
    seed: int

    def _values(self, values: dict | None) -> torch.Tensor:
        """(P, 3) parameter values: ``values`` where given, else the record point's."""
        values = values or {}
        unknown = sorted(set(values) - set(self.names))
        if unknown:
            raise ParameterError(f"{unknown[0]!r} was not recorded (recorded: {', '.join(self.names)})")
        rows = []
        for n in self.names:
            v = torch.as_tensor(values[n] if n in values else self.record_values[n], dtype=torch.float64, device=self.coefficients.device)
            rows.append(v.expand(3) if v.ndim == 0 else v)
        return torch.stack(rows)

    def monomials(self, values: dict | None = None) -> torch.Tensor:
        """(S, 3) each monomial ``prod_p v_{p,c}^k_p`` at ``values`` (differentiable)."""
        V = self._values(values)  # (P, 3)
        E = self.exponents.to(V.device, torch.float64)  # (S, P)
        return torch.prod(V[None, :, :] ** E[:, :, None], dim=1)

    def image(self, values: dict | None = None) -> torch.Tensor:
        """The image (H, W, 3) float64 at parameter ``values`` (name -> RGB; missing names keep
        their record-point values), differentiable in them; no tracing."""
        flat = torch.einsum("sc,snc->nc", self.monomials(values), self.coefficients)
        return flat.reshape(self.resolution[1], self.resolution[0], 3)

    def jacobian(self, values: dict | None = None) -> dict[str, torch.Tensor]:
        """Exact derivatives of :meth:`image`: name -> (H, W, 3), the derivative of each pixel's
        channel c with respect to the parameter's channel c (channels are independent: the
        derivative across channels is zero)."""
        V = self._values(values)  # (P, 3)
        E = self.exponents.to(V.device, torch.float64)  # (S, P)
        powers = V[None, :, :] ** E[:, :, None]  # (S, P, 3)
        out = {}
        for p, name in enumerate(self.names):
            k = E[:, p : p + 1]
            # d/dv_p of v_p^k = k v_p^(k - 1) (zero for k = 0, also where v_p = 0), times the other factors
            d = torch.where(k > 0, k * V[p][None, :] ** (k - 1).clamp_min(0), 0.0)
            others = torch.prod(torch.cat([powers[:, :p], powers[:, p + 1 :]], dim=1), dim=1)
            out[name] = torch.einsum("sc,snc->nc", d * others, self.coefficients).reshape(self.resolution[1], self.resolution[0], 3)
        return out

    @property
    def nbytes(self) -> int:
        return self.coefficients.numel() * self.coefficients.element_size()


class _RecordFilm(Film):
    """A film that decodes each contribution's monomial from its forward-mode tangent and adds its
    fixed weight to that monomial's coefficient image."""

    def __init__(self, width: int, height: int, device, radix: list[int], record: torch.Tensor):
        super().__init__(width, height, False, device)
        self.radix, self.record = radix, record  # record: (P, 3) float64 values at the record point
        self.place = [math.prod(radix[:p]) for p in range(len(radix))]
        self.rows: dict[int, int] = {}  # monomial code -> its row of ``buffer``
        self.buffer = torch.zeros(8, width * height * 3, dtype=torch.float64, device=device)

    def add(self, term: int, pixel: torch.Tensor, radiance: torch.Tensor) -> None:
        primal, tangent = fwAD.unpack_dual(radiance)
        c = primal.detach().double()
        if tangent is None:
            tangent = torch.zeros_like(primal)
        ratio = tangent.detach().double() / torch.where(c != 0, c, 1.0)
        code = torch.round(ratio)
        live = c != 0
        if bool(((ratio - code).abs() > 0.25)[live].any()):
            raise ParameterError("a contribution is not a monomial in the recorded parameters (a recorded parameter enters non-linearly)")
        code = code.long()
        key = (pixel[:, None] * 3 + torch.arange(3, device=pixel.device))[live]
        code, c = code[live], c[live]
        channel = key % 3
        # the monomial's value at the record point, to turn the contribution into its weight w
        mono = torch.ones_like(c)
        for p, (place, radix) in enumerate(zip(self.place, self.radix)):
            k = (code // place) % radix
            mono = mono * self.record[p][channel] ** k
        w = c / mono
        # one index_add: each monomial has a row of the coefficient buffer (rows added as codes appear)
        codes, inverse = torch.unique(code, return_inverse=True)
        for value in codes.tolist():
            if value not in self.rows:
                self.rows[value] = len(self.rows)
        if len(self.rows) > self.buffer.shape[0]:
            grown = self.buffer.new_zeros(max(2 * self.buffer.shape[0], len(self.rows)), self.buffer.shape[1])
            grown[: self.buffer.shape[0]] = self.buffer
            self.buffer = grown
        row = torch.tensor([self.rows[v] for v in codes.tolist()], device=key.device)[inverse]
        self.buffer.view(-1).index_add_(0, row * self.buffer.shape[1] + key, w)

    @property
    def sums(self) -> dict[int, torch.Tensor]:
        """code -> (W * H * 3,) float64 sum of the weights of that monomial's contributions."""
        return {code: self.buffer[r] for code, r in self.rows.items()}


def record_paths(
    scene: Scene,
    params,
    spp: int = 64,
    max_depth: int = 8,
    seed: int = 0,
    *,
    integrator: str = "path",
    device=None,
    memory_mb: float = 512.0,
    max_record_mb: float = 1024.0,
    progress: bool = True,
    **options,
) -> PathRecords:
    """Trace ``scene`` once and keep the estimate as a polynomial in the parameters ``params``.

    Args:
        scene: its parameter values are the record point (every recorded value must be > 0 in
            every channel: a path's weight is recovered by dividing by its monomial there).
        params: names of constant (RGB, not textured) parameters to record, list or comma-separated.
        spp, max_depth, seed: as :func:`invrender.render` (``max_depth`` finite: it bounds the
            degree of the polynomial).
        integrator: any integrator name; ``options`` are its further settings (e.g. ``rr_depth``).
        max_record_mb: refuse records whose coefficient images would exceed this.
    Returns:
        :class:`PathRecords`; ``records.image()`` equals ``render(scene, ...)`` for the same seed
        up to float rounding.
    """
    from invrender.inverse.params import check_names

    names = check_names(scene.params, params)
    if isinstance(max_depth, bool) or not isinstance(max_depth, int) or max_depth < 1:
        raise ParameterError(f"record_paths needs a finite max_depth >= 1 (it bounds the polynomial's degree), got {max_depth!r}")
    for n in names:
        v = scene.params[n]
        if v.ndim != 1:
            raise ParameterError(f"{n} is a texture: path records of textured parameters are not supported yet (record constant parameters)")
        if not bool((v.detach() > 0).all()):
            raise ParameterError(f"{n} must be > 0 in every channel at the record point, got {v.detach().tolist()}")
    # radix: one more than the largest degree (emission: one emitter or ambient term per contribution)
    radix = [2 if kind_of(n).key == "emission" else max_depth for n in names]
    if math.prod(radix) > MAX_CODES:
        raise ParameterError(f"too many parameters for one record ({len(names)} at max_depth {max_depth}: {math.prod(radix)} exponent codes, at most {MAX_CODES}); record fewer")
    w, h = scene.resolution
    if 8 * w * h * 3 > max_record_mb * 2**20:
        raise ParameterError(f"a {w}x{h} record needs {8 * w * h * 3 / 2**20:.0f} MiB per monomial, over max_record_mb={max_record_mb:g}")
    model = make_integrator(integrator, max_depth=max_depth, **options)
    settings = RenderSettings(spp=spp, seed=seed, memory_mb=memory_mb, progress=progress)
    device = torch.device(device) if device is not None else scene.device
    record = torch.stack([scene.params[n].detach().to(device, torch.float64) for n in names])
    place = [math.prod(radix[:p]) for p in range(len(radix))]
    films: dict[int, _RecordFilm] = {}

    with fwAD.dual_level(), torch.no_grad():
        duals = {n: fwAD.make_dual(scene.params[n].detach().to(device), scene.params[n].detach().to(device) * place[p]) for p, n in enumerate(names)}
        ctx = model.context(scene, settings, device, params=duals)

        def work(worker: int, state) -> None:
            if worker not in films:
                films[worker] = _RecordFilm(w, h, device, radix, record)
            model.trace(ctx, state, films[worker])

        for_each_chunk(scene, settings, device, work, grad=False)

    sums: dict[int, torch.Tensor] = {}
    for film in films.values():
        for code, img in film.sums.items():
            sums[code] = sums[code] + img if code in sums else img
    codes = sorted(sums)
    if len(codes) * 8 * w * h * 3 > max_record_mb * 2**20:
        raise ParameterError(f"the record holds {len(codes)} monomials, {len(codes) * 8 * w * h * 3 / 2**20:.0f} MiB, over max_record_mb={max_record_mb:g}")
    exponents = torch.tensor([[(c // pl) % r for pl, r in zip(place, radix)] for c in codes], dtype=torch.int64).reshape(len(codes), len(names))
    coefficients = (torch.stack([sums[c] for c in codes]) if codes else torch.zeros(0, w * h * 3, dtype=torch.float64)).reshape(len(codes), w * h, 3) / spp
    return PathRecords(tuple(names), exponents, coefficients, (w, h), {n: record[p].clone() for p, n in enumerate(names)}, spp, seed)
