"""Path records: the traced Monte Carlo estimate as an explicit polynomial in the parameters.

Sampling never depends on a differentiable parameter (``docs/architecture.md``, detached sampling),
so once paths are traced every contribution a path adds to a pixel is a *monomial* in the
parameters of polynomial kinds (not a roughness: its D and G terms enter non-linearly, and
:func:`record_paths` refuses it), per colour channel:

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

**Textured parameters.** A texture (h, w, 3) enters a vertex through its filter (bilinear, or nearest: Scene.texture_sampling), a linear
form ``sum_j b_j x_{t_j}`` of four texels, not as a monomial. Its digit in the code still counts its
factors (the lookup is linear, so its tangent is its value times the digit's place), and the film is
told where each path met the textured material (``Film.visit``): a contribution with k factors of the
texture takes its path's first k textured vertices, which are all of them, or all but the vertex the
contribution is added at (an emitter seen there carries no reflection factor of it). Expanding the
product of the k linear forms gives up to 4^k monomials in single texels, each weighted
``w prod_j b_j``; they are summed per pixel, code and multiset of texels, so a record's size
saturates as spp grows instead of growing with it. Every texel is a variable of its own (three
channels), and the record keeps these monomials in a sparse table per degree k (:class:`TexelTerms`),
within a memory budget.

**Environment maps.** An emitter infinitely far away whose emission is a texture read through a
linear filter by direction (``envmap``: :meth:`Light.texels <invrender.core.lights.Light.texels>`)
is a textured parameter too: the integrators tell the film the direction of each contribution that
may end on such an emitter (``Film.arrive``, just before it is added), the record film looks up the
texels and weights the map reads there, and a contribution with the map's factor (its digit: 0 or
1) takes them as one more linear form, multiplied out with the path's textured vertices as above.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import torch
import torch.autograd.forward_ad as fwAD

from invrender.errors import ParameterError
from invrender.registry import EMITTERS
from invrender.scene.kinds import kind_of
from invrender.scene.scene import Scene, check_names
from invrender.core import fused
from invrender.core.driver import RenderSettings, SamplePlan, film_weights, for_each_chunk
from invrender.core.film import Film
from invrender.plugins.integrators import make_integrator
from invrender.core.textures import bilinear
from invrender.scene.textures import DEFAULT, TextureSampling

#: largest exponent code the float32 trace resolves exactly (its relative rounding stays < 1e-6)
MAX_CODES = 1 << 16
#: texel monomials expanded at once (bounds the working memory of the expansion)
EXPAND_ROWS = 1 << 21




@dataclass(frozen=True)
class TexelTerms:
    """The recorded monomials with K texel factors (one table per K >= 1).

    Attributes:
        pixel: (U,) int64 flat pixel index (row * width + column).
        term: (U,) int64 row of :attr:`PathRecords.texel_exponents`: the exponents of the constant
            parameters in the monomial.
        texels: (U, K) int64 variable rows (:meth:`PathRecords.variables`) of the K texel factors,
            sorted (a texel met twice appears twice).
        coefficients: (U, 3) float64 per channel, the sum over a pixel's paths of ``w prod_j b_j``,
            divided by spp.
    """

    pixel: torch.Tensor
    term: torch.Tensor
    texels: torch.Tensor
    coefficients: torch.Tensor

    @property
    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in (self.pixel, self.term, self.texels, self.coefficients))


@dataclass(frozen=True)
class PathRecords:
    """A traced estimate as a polynomial in the recorded parameters.

    The parameters' values are *variables*, rows of three channels: a constant parameter is one
    row, a texture (h, w, 3) is h * w rows (its texels in row-major order); see :meth:`variables`.

    Attributes:
        names: the recorded parameters.
        exponents: (S, P) int64, the exponent of each parameter in each of the S monomials that
            have no texel factor (a textured parameter's column is 0 there).
        coefficients: (S, H * W, 3) float64, per monomial the sum over a pixel's paths of their
            fixed weights w, divided by spp.
        resolution: (width, height).
        record_values: name -> (3,) or (h, w, 3) the values the paths were traced at (of the
            last pass, for a record that :func:`accumulate` summed).
        spp: samples per pixel traced (of every pass summed).
        seed: the seed of the traced paths (of the last pass).
        texel_exponents: (Q, P) int64 the constant parameters' exponents of the monomials with
            texel factors (textured columns 0), indexed by ``TexelTerms.term``.
        texel_terms: the monomials with texel factors, one table per degree K (empty without
            textured parameters).
    """

    names: tuple[str, ...]
    exponents: torch.Tensor
    coefficients: torch.Tensor
    resolution: tuple[int, int]
    record_values: dict
    spp: int
    seed: int
    texel_exponents: torch.Tensor | None = None
    texel_terms: tuple[TexelTerms, ...] = ()

    @property
    def textured(self) -> list[bool]:
        """(P,) is each parameter a texture?"""
        return [self.record_values[n].ndim == 3 for n in self.names]

    @property
    def offsets(self) -> list[int]:
        """The first variable row of each parameter (P + 1 entries: the last is the row count)."""
        out = [0]
        for n in self.names:
            out.append(out[-1] + self.record_values[n].numel() // 3)
        return out

    def variables(self, values: dict | None = None) -> torch.Tensor:
        """(N_var, 3) float64 every parameter's value as variable rows: ``values`` where given
        (name -> RGB, a scalar, or for a texture (h, w, 3)), else the record point's."""
        values = values or {}
        unknown = sorted(set(values) - set(self.names))
        if unknown:
            raise ParameterError(f"{unknown[0]!r} was not recorded (recorded: {', '.join(self.names)})")
        rows = []
        for n in self.names:
            shape = self.record_values[n].shape
            v = torch.as_tensor(values[n] if n in values else self.record_values[n], dtype=torch.float64, device=self.coefficients.device)
            if len(shape) == 3:
                if v.shape != shape:
                    raise ParameterError(f"{n} was recorded as a {shape[0]}x{shape[1]} texture; got a value of shape {tuple(v.shape)}")
                rows.append(v.reshape(-1, 3))
            else:
                rows.append((v.expand(3) if v.ndim == 0 else v)[None, :])
        return torch.cat(rows)

    def _per_parameter(self, V: torch.Tensor) -> torch.Tensor:
        """(P, 3) each constant parameter's row of ``V``; 1 for textures (their factors are the
        texel terms')."""
        offsets = self.offsets
        return torch.stack([torch.ones(3, dtype=V.dtype, device=V.device) if tex else V[offsets[p]] for p, tex in enumerate(self.textured)])

    @functools.cached_property
    def _by_channel(self) -> torch.Tensor:
        """(3, H * W, S) the coefficients channel-major: every evaluation is one batched
        matrix product per channel (a BLAS call, not an einsum over a strided layout)."""
        return self.coefficients.permute(2, 1, 0).contiguous()

    def _dense(self, factors: torch.Tensor) -> torch.Tensor:
        """(H * W, 3, K) ``sum_s coefficients[s, n, c] factors[s, c, k]`` for ``factors`` (S, 3, K)."""
        return torch.bmm(self._by_channel, factors.permute(1, 0, 2)).permute(1, 0, 2)

    def monomials(self, values: dict | None = None) -> torch.Tensor:
        """(S, 3) each texel-free monomial ``prod_p v_{p,c}^k_p`` at ``values`` (differentiable)."""
        return _power_products(self._per_parameter(self.variables(values)), self.exponents)

    def image(self, values: dict | None = None) -> torch.Tensor:
        """The image (H, W, 3) float64 at parameter ``values`` (name -> value; missing names keep
        their record-point values), differentiable in them; no tracing."""
        V = self.variables(values)
        Vp = self._per_parameter(V)
        flat = self._dense(_power_products(Vp, self.exponents)[:, :, None])[:, :, 0]
        if self.texel_terms:
            M = _power_products(Vp, self.texel_exponents)  # (Q, 3)
            for g in self.texel_terms:
                flat = flat.index_add(0, g.pixel, g.coefficients * M[g.term] * V[g.texels].prod(1))
        return flat.reshape(self.resolution[1], self.resolution[0], 3)

    def jacobian(self, values: dict | None = None) -> dict[str, torch.Tensor]:
        """Exact derivatives of :meth:`image`: name -> (H, W, 3) for a constant, the derivative of
        each pixel's channel c with respect to the parameter's channel c, or (H, W, h, w, 3) for a
        texture, with respect to each texel's channel c (channels are independent: derivatives
        across channels are zero)."""
        V = self.variables(values)
        Vp = self._per_parameter(V)
        W, H = self.resolution
        offsets = self.offsets
        M = _power_products(Vp, self.texel_exponents) if self.texel_terms else None
        constant = [p for p, tex in enumerate(self.textured) if not tex]
        # every constant parameter's derivative of the texel-free part at once: (N, 3, P')
        dense = self._dense(torch.stack([_power_derivative(Vp, self.exponents, p) for p in constant], dim=2)) if constant else None
        out = {}
        for p, name in enumerate(self.names):
            if self.textured[p]:
                h, w = self.record_values[name].shape[:2]
                T = h * w
                if H * W * T * 24 > 2**31:
                    raise ParameterError(f"the Jacobian of {H}x{W} pixels by the {h}x{w} texels of {name} needs {H * W * T * 24 / 2**30:.1f} GiB; use fewer pixels or texels")
                J = torch.zeros(H * W * T, 3, dtype=torch.float64, device=V.device)
                for g in self.texel_terms:
                    F = V[g.texels]  # (U, K, 3)
                    m = g.coefficients * M[g.term]
                    for k in range(F.shape[1]):
                        t = g.texels[:, k] - offsets[p]
                        on = ((t >= 0) & (t < T)).nonzero()[:, 0]
                        others = F[on, :k].prod(1) * F[on, k + 1 :].prod(1)
                        J.index_add_(0, g.pixel[on] * T + t[on], m[on] * others)
                out[name] = J.reshape(H, W, h, w, 3)
                continue
            flat = dense[:, :, constant.index(p)]
            for g in self.texel_terms:
                flat = flat.index_add(0, g.pixel, g.coefficients * _power_derivative(Vp, self.texel_exponents, p)[g.term] * V[g.texels].prod(1))
            out[name] = flat.reshape(H, W, 3)
        return out

    @property
    def nbytes(self) -> int:
        return self.coefficients.numel() * self.coefficients.element_size() + sum(g.nbytes for g in self.texel_terms)


def _power_products(V: torch.Tensor, E: torch.Tensor) -> torch.Tensor:
    """(S, 3) ``prod_p V[p]^E[s, p]`` for values ``V`` (P, 3) and exponents ``E`` (S, P)."""
    E = E.to(V.device, torch.float64)
    return torch.prod(V[None, :, :] ** E[:, :, None], dim=1)


def _power_derivative(V: torch.Tensor, E: torch.Tensor, p: int) -> torch.Tensor:
    """(S, 3) the derivative of :func:`_power_products` with respect to ``V[p]`` (per channel)."""
    E = E.to(V.device, torch.float64)
    powers = V[None, :, :] ** E[:, :, None]  # (S, P, 3)
    k = E[:, p : p + 1]
    # d/dv of v^k = k v^(k - 1) (zero for k = 0, also where v = 0), times the other factors
    d = torch.where(k > 0, k * V[p][None, :] ** (k - 1).clamp_min(0), 0.0)
    return d * torch.prod(torch.cat([powers[:, :p], powers[:, p + 1 :]], dim=1), dim=1)


@dataclass(frozen=True)
class _TextureSlot:
    """A recorded textured parameter: its digit ``p`` of the code, the scene material it belongs to
    (-1 for an emitter's map), its texture size and its first variable row; for a map of an emitter
    infinitely far away, ``lookup(d)`` gives the texels (N, J) and weights (N, J) its radiance along
    world directions d reads (:meth:`Light.texels <invrender.core.lights.Light.texels>`)."""

    p: int
    name: str
    material: int
    h: int
    w: int
    offset: int
    lookup: object = None
    #: how the material's texture is read (its ``to_uv``, filter and wrap)
    sampling: TextureSampling = DEFAULT

    @property
    def sky(self) -> bool:
        return self.lookup is not None


class _History:
    """Per path (film index), the vertices where it met one textured material, in order: their
    texels' variable rows (n, D, 4), filter weights (n, D, 4), the path's vertex count at each
    (n, D), and how many there are (n,)."""

    def __init__(self, n: int, depth: int, device):
        self.rows = torch.zeros(n, depth, 4, dtype=torch.int64, device=device)
        self.weights = torch.zeros(n, depth, 4, dtype=torch.float64, device=device)
        self.vertex = torch.full((n, depth), -1, dtype=torch.int64, device=device)
        self.count = torch.zeros(n, dtype=torch.int64, device=device)

    def extend(self, parents: torch.Tensor) -> None:
        """Append copies of the paths ``parents`` (branches inherit their parent's history)."""
        for f in ("rows", "weights", "vertex", "count"):
            t = getattr(self, f)
            setattr(self, f, torch.cat([t, t[parents]]))


class _RecordFilm(Film):
    """A film that decodes each contribution's monomial from its forward-mode tangent and adds its
    fixed weight to that monomial's coefficient image; contributions with texel factors are
    expanded into texel monomials and summed into sparse tables (:class:`TexelTerms`).

    Film indices are paths (one per path of the current chunk, :meth:`begin`; branches get new
    ones), so the film can follow each path's textured vertices.

    Where the fused bounce traces the record (:func:`record_paths`), it computes each
    contribution's code itself (:attr:`fused_places`) and adds it with :meth:`add_coded`: no
    forward-mode tangents."""

    #: (S,) int64 the place of each fused-bounce slot's exponent in a code (the scene's materials,
    #: then its emitters; 0: not recorded), when the fused bounce traces the record; None: tangents
    fused_places: torch.Tensor | None = None

    def __init__(self, width: int, height: int, device, radix: list[int], record: torch.Tensor, slots: list[_TextureSlot], material_of: torch.Tensor, depth: int, budget: float):
        super().__init__(width, height, False, device)
        self.radix, self.record = radix, record  # record: (N_var, 3) float64 variables at the record point
        self.place = [math.prod(radix[:p]) for p in range(len(radix))]
        self.slots, self.material_of, self.depth, self.budget = slots, material_of, depth, budget
        self.textured = {s.p for s in slots}
        self.first_row = [int(r) for r in _first_rows(record, slots, len(radix))]
        self.bound = max(width * height, math.prod(radix), record.shape[0])  # of every key entry
        self.rows: dict[int, int] = {}  # monomial code -> its row of ``buffer``
        self.row_of = torch.full((math.prod(radix),), -1, dtype=torch.int64, device=device)  # the same as a table
        self.buffer = torch.zeros(8, width * height * 3, dtype=torch.float64, device=device)
        self.tables: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}  # K -> (keys (U, 2 + K), coefficients (U, 3))
        self.pending: dict[int, list[tuple[torch.Tensor, torch.Tensor]]] = {}

    def begin(self, pixel: torch.Tensor, footprint=None) -> torch.Tensor:
        """Start a chunk whose paths write to ``pixel`` (N,); returns their film indices. With a
        filter, ``footprint`` (:class:`~invrender.core.rfilter.Footprint` of the N paths): each
        contribution lands in every pixel of its path's footprint, weighted."""
        self.pixel_of = pixel
        self.footprint = footprint
        n = pixel.shape[0]
        self.visits = torch.zeros(n, dtype=torch.int64, device=pixel.device)
        # a map's history holds one entry: the texels of the next contribution's arrival (arrive)
        self.history = [_History(n, 1 if s.sky else self.depth, pixel.device) for s in self.slots]
        return torch.arange(n, device=pixel.device)

    def branch(self, path: torch.Tensor) -> torch.Tensor:
        new = torch.arange(self.pixel_of.shape[0], self.pixel_of.shape[0] + path.numel(), device=path.device)
        self.pixel_of = torch.cat([self.pixel_of, self.pixel_of[path]])
        if self.footprint is not None:
            f = self.footprint
            self.footprint = type(f)(torch.cat([f.index, f.index[path]]), torch.cat([f.weight, f.weight[path]]))
        self.visits = torch.cat([self.visits, self.visits[path]])
        for hist in self.history:
            hist.extend(path)
        return new

    def visit(self, path: torch.Tensor, s) -> None:
        for slot, hist in zip(self.slots, self.history):
            if slot.sky:
                continue
            on = (self.material_of[s.tri] == slot.material).nonzero()[:, 0]
            if on.numel():
                at = path[on]
                rows, weights = bilinear(slot.h, slot.w, s.uv[on], slot.sampling)
                k = hist.count[at]
                hist.rows[at, k] = rows + slot.offset
                hist.weights[at, k] = weights.double()
                hist.vertex[at, k] = self.visits[at]
                hist.count[at] += 1
        self.visits[path] += 1

    def arrive(self, path: torch.Tensor, d: torch.Tensor) -> None:
        """Note, per path, the texels of each recorded map that radiance arriving along ``d`` reads:
        the next contribution of the path with a factor of the map takes them (and clears them)."""
        for slot, hist in zip(self.slots, self.history):
            if slot.sky:
                rows, weights = slot.lookup(d)
                hist.rows[path, 0] = rows + slot.offset
                hist.weights[path, 0] = weights.double()
                hist.count[path] = 1

    def add(self, term: int, path: torch.Tensor, radiance: torch.Tensor) -> None:
        try:
            self._add(path, radiance)
        finally:
            for slot, hist in zip(self.slots, self.history):
                if slot.sky:
                    hist.count[path] = 0  # an arrival serves the one contribution after it

    def add_coded(self, term: int, path: torch.Tensor, code: torch.Tensor, radiance: torch.Tensor) -> None:
        """Contributions ``radiance`` (L, 3) at the record point of paths ``path`` (L,), their
        monomials' codes ``code`` (L,) given (-1: no contribution), from the fused bounce."""
        c = radiance.double()
        live = (code >= 0)[:, None] & (c != 0)
        code = code.clamp_min(0)[:, None].expand(-1, 3)
        key, code, c, live = self._spread(path, code, torch.where(live, c, 0.0), live)
        self._add_dense(code.reshape(-1), key.reshape(-1), c.reshape(-1), live.reshape(-1))

    def _spread(self, path, code, c, live):
        """(film entries, codes, contributions, live) of contributions ``c`` (L, 3) with codes and
        liveness (L, 3) of paths ``path`` (L,): entries ``pixel * 3 + channel`` (L, 3) in the
        path's pixel, or with a filter (L * K, 3) in each pixel of its footprint, ``c`` weighted."""
        channel = torch.arange(3, device=path.device)
        if self.footprint is None:
            return self.pixel_of[path][:, None] * 3 + channel, code, c, live
        index, weight = self.footprint.index[path], self.footprint.weight[path]  # (L, K)
        on = live[:, None, :] & (weight != 0)[:, :, None]
        key = index[:, :, None] * 3 + channel
        value = c[:, None, :] * weight[:, :, None]
        return key.reshape(-1, 3), code[:, None, :].expand_as(key).reshape(-1, 3), value.reshape(-1, 3), on.reshape(-1, 3)

    def _add(self, path: torch.Tensor, radiance: torch.Tensor) -> None:
        primal, tangent = fwAD.unpack_dual(radiance)
        c = primal.detach().double()  # (L, 3) contributions at the record point
        if tangent is None:
            tangent = torch.zeros_like(primal)
        live = c != 0
        ratio = torch.where(live, tangent.detach().double() / torch.where(live, c, 1.0), 0.0)
        code = torch.round(ratio)
        if bool(((ratio - code).abs() > 0.25).any()):  # 0 where c == 0 (code 0, adding 0)
            raise ParameterError("a contribution is not a monomial in the recorded parameters (a recorded parameter enters non-linearly)")
        code = code.long()
        if not self.slots:
            # every contribution is added at the record point: its monomial there is divided out
            # once per code and channel when the record is read (sums), not per contribution
            key, code, c, live = self._spread(path, code, c, live)
            self._add_dense(code.reshape(-1), key.reshape(-1), c.reshape(-1), live.reshape(-1))
            return
        key = self.pixel_of[path][:, None] * 3 + torch.arange(3, device=path.device)  # (L, 3) film entries
        channel = torch.arange(3, device=path.device).expand_as(live)[live]
        path, key = path[:, None].expand_as(live)[live], key[live]
        code, c = code[live], c[live]
        digits = [(code // place) % radix for place, radix in zip(self.place, self.radix)]
        degree = sum(digits[s.p] for s in self.slots)
        plain = degree == 0
        self._add_dense(code[plain], key[plain], c[plain], None)
        textured = (~plain).nonzero()[:, 0]
        if textured.numel():
            # the constant parameters' monomial at the record point, to turn the contribution into its weight w
            ch = channel[textured]
            mono = torch.ones(textured.numel(), dtype=torch.float64, device=c.device)
            for p, k in enumerate(digits):
                if p not in self.textured:
                    mono = mono * self.record[self.first_row[p], ch] ** k[textured]
            self._add_textured(path[textured], ch, code[textured], c[textured] / mono, torch.stack([digits[s.p][textured] for s in self.slots], dim=1))

    def _add_dense(self, code: torch.Tensor, key: torch.Tensor, c: torch.Tensor, live: torch.Tensor | None) -> None:
        """Add contributions ``c`` (L,) at the record point to monomial ``code`` (L,) at film
        entries ``key`` (L,) (pixel * 3 + channel); ``live`` (L,): which are nonzero (None: all;
        a zero one adds nothing and creates no monomial)."""
        if not code.numel():
            return
        # one index_add: each monomial has a row of the buffer (rows added as codes appear, found
        # through a table of every possible code: no sort)
        seen = torch.zeros_like(self.row_of).index_add_(0, code, live.long() if live is not None else torch.ones_like(code))
        new = ((seen > 0) & (self.row_of < 0)).nonzero()[:, 0]
        if new.numel():
            self.row_of[new] = torch.arange(len(self.rows), len(self.rows) + new.numel(), device=self.row_of.device)
            self.rows.update({int(v): len(self.rows) + i for i, v in enumerate(new.tolist())})
        if len(self.rows) > self.buffer.shape[0]:
            grown = self.buffer.new_zeros(max(2 * self.buffer.shape[0], len(self.rows)), self.buffer.shape[1])
            grown[: self.buffer.shape[0]] = self.buffer
            self.buffer = grown
        self.buffer.view(-1).index_add_(0, self.row_of[code].clamp_min(0) * self.buffer.shape[1] + key, c)  # a zero c may land anywhere

    def _add_textured(self, path, channel, code, w, counts) -> None:
        """Contributions with texel factors: ``counts`` (L, slots) how many factors of each texture.
        Each takes its path's first ``count`` vertices on that texture's material."""
        for slot, hist, k in zip(self.slots, self.history, counts.T):
            n = hist.count[path]
            if slot.sky:  # at most one factor, from the arrival noted just before
                if not bool((k <= n).all()):
                    raise ParameterError(f"{slot.name} enters a contribution whose direction the path records were not told (an integrator that reads the map without Film.arrive); fit it with adam")
                continue
            last = hist.vertex[path, (n - 1).clamp_min(0)]
            ok = (k == n) | ((k == n - 1) & (last == self.visits[path] - 1))
            if not bool(ok.all()):
                raise ParameterError(f"{slot.name} enters a contribution through a vertex the path records did not see (an integrator that evaluates a texture away from its path's vertices); record it as a constant or fit it with adam")
        combined = torch.zeros_like(counts[:, 0])
        for j in range(counts.shape[1]):
            combined = combined * (self.depth + 1) + counts[:, j]  # each count <= depth
        values, inverse = torch.unique(combined, return_inverse=True)
        for g, value in enumerate(values.tolist()):
            ks = [(value // (self.depth + 1) ** (counts.shape[1] - 1 - j)) % (self.depth + 1) for j in range(counts.shape[1])]
            i = (inverse == g).nonzero()[:, 0]
            rows = torch.cat([hist.rows[path[i], :k] for hist, k in zip(self.history, ks)], dim=1)  # (G, K, 4)
            weights = torch.cat([hist.weights[path[i], :k] for hist, k in zip(self.history, ks)], dim=1)
            # divide out the texel factors' values at the record point: w becomes the fixed weight
            factor = (weights * self.record[rows, channel[i][:, None, None]]).sum(-1)  # (G, K)
            self._expand(self.pixel_of[path[i]], code[i], channel[i], rows, weights, w[i] / factor.prod(1))

    def _expand(self, pixel, code, channel, rows, weights, w) -> None:
        """Multiply out the K linear forms of each contribution: 4^K texel monomials, each weighted
        by its filter weights' product; summed per (pixel, code, sorted texels)."""
        K = rows.shape[1]
        corners = torch.cartesian_prod(*[torch.arange(4, device=rows.device)] * K).reshape(-1, K)  # (4^K, K)
        factor = torch.arange(K, device=rows.device)
        batch = max(1, EXPAND_ROWS // corners.shape[0])
        for a in range(0, rows.shape[0], batch):
            r, b, ww = rows[a : a + batch], weights[a : a + batch], w[a : a + batch]
            texels = r[:, factor, corners].sort(dim=-1).values  # (G, 4^K, K)
            value = ww[:, None] * b[:, factor, corners].prod(-1)  # (G, 4^K)
            keep = value != 0
            G = r.shape[0]
            head = torch.stack([pixel[a : a + batch], code[a : a + batch]], dim=1)[:, None, :].expand(G, corners.shape[0], 2)
            keys = torch.cat([head, texels], dim=-1)[keep]
            ch = channel[a : a + batch, None].expand(G, corners.shape[0])[keep]
            coef = torch.zeros(keys.shape[0], 3, dtype=torch.float64, device=keys.device)
            coef[torch.arange(keys.shape[0], device=keys.device), ch] = value[keep]
            self.pending.setdefault(K, []).append(_sum_rows(keys, coef, self.bound))
            if sum(k.shape[0] for k, _ in self.pending[K]) > max(1 << 20, self.tables.get(K, (torch.empty(0),))[0].shape[0]):
                self._merge(K)

    def _merge(self, K: int) -> None:
        parts = ([self.tables[K]] if K in self.tables else []) + self.pending.pop(K, [])
        if parts:
            self.tables[K] = _sum_rows(torch.cat([k for k, _ in parts]), torch.cat([c for _, c in parts]), self.bound)
        nbytes = self.buffer[: len(self.rows)].numel() * 8 + sum(k.numel() * 8 + c.numel() * 8 for k, c in self.tables.values())
        if nbytes > self.budget:
            names = ", ".join(s.name for s in self.slots)
            raise ParameterError(f"the path record of {names} outgrew max_record_mb={self.budget / 2**20:g} ({nbytes / 2**20:.0f} MiB so far); lower spp, max_depth or the texture's resolution, or raise max_record_mb")

    def texel_tables(self) -> dict[int, tuple[torch.Tensor, torch.Tensor]]:
        """K -> (keys (U, 2 + K): pixel, code, texel rows; coefficients (U, 3) sums of weights)."""
        for K in list(self.pending):
            self._merge(K)
        return self.tables

    @property
    def sums(self) -> dict[int, torch.Tensor]:
        """code -> (W * H * 3,) float64 sum of the weights of that monomial's contributions (the
        buffer's sums of contributions at the record point divided by the monomial there)."""
        out = {}
        for code, r in self.rows.items():
            mono = torch.ones(3, dtype=torch.float64, device=self.buffer.device)
            for p, (place, radix) in enumerate(zip(self.place, self.radix)):
                if p not in self.textured:
                    mono = mono * self.record[self.first_row[p]] ** ((code // place) % radix)
            out[code] = (self.buffer[r].reshape(-1, 3) / mono).reshape(-1)
        return out


def _with_lookup(slot: _TextureSlot, lights) -> _TextureSlot:
    """``slot`` of an emitter's map (``slot.lookup`` its scene emitter index until now) with the
    lookup of the light instance that holds that emitter."""
    e = slot.lookup
    light = next(light for light in lights.lights if e in light.emitters)
    k = light.emitters.index(e)
    return dataclasses.replace(slot, lookup=lambda d: light.texels(k, d))


def _first_rows(record: torch.Tensor, slots: list[_TextureSlot], count: int) -> list[int]:
    """Each parameter's first variable row (constants are one row each; textures many)."""
    sizes = {s.p: s.h * s.w for s in slots}
    rows, at = [], 0
    for p in range(count):
        rows.append(at)
        at += sizes.get(p, 1)
    return rows


def _sum_rows(keys: torch.Tensor, coef: torch.Tensor, bound: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Rows of ``coef`` (M, 3) with equal ``keys`` (M, J) summed: (unique keys (U, J), sums (U, 3)).
    Every key entry is < ``bound``; when ``bound^J`` fits in 62 bits the rows are compared as one
    integer each (a 1-D sort: an order of magnitude faster than comparing rows)."""
    J = keys.shape[1]
    if J * math.log2(max(bound, 2)) < 62:
        flat = torch.zeros(keys.shape[0], dtype=torch.int64, device=keys.device)
        for j in range(J):
            flat = flat * bound + keys[:, j]
        _, inverse = torch.unique(flat, return_inverse=True)
        unique = keys.new_empty(int(inverse.max()) + 1 if inverse.numel() else 0, J)
        unique[inverse] = keys  # duplicates write equal rows
    else:
        unique, inverse = torch.unique(keys, dim=0, return_inverse=True)
    return unique, coef.new_zeros(unique.shape[0], 3).index_add_(0, inverse, coef)


def _fused_places(scene: Scene, model, settings: RenderSettings, device, names: list[str], place: list[int]) -> torch.Tensor | None:
    """(S,) int64 each fused-bounce slot's place in the record's codes, when the fused bounce
    applies to the record's render and carries every recorded parameter
    (:func:`invrender.core.fused.slot_index`); else None (forward-mode tangents)."""
    with torch.no_grad():
        scene_tables = model.fused_scene(model.context(scene, settings, device))
    if scene_tables is None:
        return None
    index = fused.slot_index(scene, scene_tables)
    if any(n not in index for n in names):
        return None
    places = torch.zeros(fused.slots(scene_tables), dtype=torch.int64, device=device)
    for p, n in enumerate(names):
        places[index[n]] = place[p]
    return places


def record_obstacle(scene: Scene, names) -> str | None:
    """Why path records cannot represent the scene parameters ``names`` (the first reason, one
    line naming the parameter), or None when they can:

    - a kind that is not a polynomial factor of a path's weight (a roughness);
    - a material's parameter that is not one monomial factor of its weights (its type's
      ``not_polynomial``: a rough plastic's two lobes);
    - the emission of an emitter infinitely far away when the scene has more than one: a ray that
      leaves the scene sees their radiances added (``Lights.escaped``), so each such contribution
      is a sum of the maps' values, not one monomial in any of them.
    """
    infinite = [e for i, e in enumerate(scene.emitters) if EMITTERS[scene.emitter_spec(i).type].infinite]
    for n in names:
        kind = kind_of(n)
        if kind.adam_only:
            return f"{n} is a shading normal ({kind.key}: it turns the frame every BSDF is evaluated in), not a polynomial factor of a path's weight"
        if scene.params[n].ndim == 2:
            return f"{n} is per vertex (a mesh attribute), which path records do not follow"
        if not kind.polynomial:
            return f"{n} is a {kind.key}, not a polynomial factor of a path's weight"
        owner, _, key = n.rpartition(".")
        if owner not in scene.materials:  # a nested material's parameter (a blend's "NAME.bsdf_0.reflectance"): its material's
            outer = next((m for m in scene.materials if n.startswith(m + ".")), None)
            owner, key = (outer, n[len(outer) + 1 :]) if outer is not None else (owner, key)
        if owner in scene.materials:
            spec = scene.material_spec(scene.materials.index(owner))
            why = spec.spec.not_polynomial(key, spec.constants)
            if why:
                return f"{n}: {why}"
        if kind.key == "emission" and owner in infinite and len(infinite) > 1:
            others = ", ".join(e for e in infinite if e != owner)
            return (f"{n}: emitter {owner!r} shares the rays that leave the scene with the other emitter(s) infinitely far away ({others}), "
                    f"whose radiance adds to its own, so a contribution is a sum, not one monomial in {n}")
    return None


#: what a refusal of :func:`record_paths` suggests for shading normals (``NAME.normals``,
#: ``NAME.normalmap``), which neither records nor forward-mode re-traced renders follow
ADAM_ONLY = "fit it with Adam (ir.fit's solver 'adam', which it chooses for normals)"
#: what a refusal of :func:`record_paths` suggests instead
INSTEAD = "ir.fit fits it with solver 'lm' or 'gauss_newton' on re-traced renders (forward-mode Jacobians), as ir.identifiability analyses it, or with solver 'adam'"


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
    sampler: str = "stratified",
    first_sample: int = 0,
    **options,
) -> PathRecords:
    """Trace ``scene`` once and keep the estimate as a polynomial in the parameters ``params``.

    Args:
        scene: its parameter values are the record point (every recorded value must be > 0 in
            every channel and texel: a path's weight is recovered by dividing by its monomial there).
        params: names of parameters to record (list or comma-separated; polynomial kinds only,
            not a roughness): constants (RGB) and
            textured reflectances (per texel), and environment maps (``envmap``'s ``NAME.emission``,
            per texel: every contribution ending on the map is linear in the four texels its
            direction reads).
        spp, max_depth, seed: as :func:`invrender.render` (``max_depth`` finite: it bounds the
            degree of the polynomial).
        integrator: any integrator name; ``options`` are its further settings (e.g. ``rr_depth``).
        sampler: how pixel samples are drawn, as :func:`invrender.render`.
        first_sample: trace every pixel's samples ``first_sample .. first_sample + spp - 1`` of
            ``seed`` (a pass, as adaptive sampling's: passes over disjoint ranges are independent,
            and :func:`accumulate` sums them into the record of all their samples).
        max_record_mb: refuse records that would exceed this (one-line error naming the
            parameters; with textures it is checked while tracing).
    Returns:
        :class:`PathRecords`; ``records.image()`` equals ``render(scene, ...)`` for the same seed
        up to float rounding.
    """
    names = check_names(scene.params, params)
    why = record_obstacle(scene, names)
    if why:
        normals = [n for n in names if kind_of(n).adam_only]
        raise ParameterError(f"{why}: path records cannot represent it; {ADAM_ONLY if normals else INSTEAD}")
    if not scene.film.is_box and any(scene.params[n].ndim == 3 for n in names):
        raise ParameterError(f"path records of textured parameters support the box filter only, and scene {scene.name!r} has the {scene.film.filter.type_name!r} filter: record with filter='box' or fit with solver 'adam'")
    if isinstance(max_depth, bool) or not isinstance(max_depth, int) or max_depth < 1:
        raise ParameterError(f"record_paths needs a finite max_depth >= 1 (it bounds the polynomial's degree), got {max_depth!r}")
    slots, offset = [], 0
    for p, n in enumerate(names):
        v = scene.params[n]
        if v.ndim == 3:
            owner = n.rpartition(".")[0]
            if kind_of(n).key == "emission" and owner in scene.emitters and EMITTERS[scene.emitter_spec(scene.emitters.index(owner)).type].texel_lookup:
                slots.append(_TextureSlot(p, n, -1, v.shape[0], v.shape[1], offset, scene.emitters.index(owner)))  # its lookup once the lights exist
            elif kind_of(n).key == "emission" or owner not in scene.materials:
                raise ParameterError(f"{n} is a textured emission of a type without a texel lookup: path records follow textures of materials and environment maps (record a constant emission, or fit it with adam)")
            else:
                slots.append(_TextureSlot(p, n, scene.materials.index(owner), v.shape[0], v.shape[1], offset, sampling=scene.texture_sampling.get(n, DEFAULT)))
        offset += v.numel() // 3
        if not bool((v.detach() > 0).all()):
            raise ParameterError(f"{n} must be > 0 in every channel at the record point, got {v.detach().tolist() if v.ndim == 1 else 'a texture with a texel <= 0'}")
    # radix: one more than the largest degree (emission: one emitter or ambient term per contribution)
    radix = [2 if kind_of(n).key == "emission" else max_depth for n in names]
    if math.prod(radix) > MAX_CODES:
        raise ParameterError(f"too many parameters for one record ({len(names)} at max_depth {max_depth}: {math.prod(radix)} exponent codes, at most {MAX_CODES}); record fewer")
    w, h = scene.resolution
    if 8 * w * h * 3 > max_record_mb * 2**20:
        raise ParameterError(f"a {w}x{h} record needs {8 * w * h * 3 / 2**20:.0f} MiB per monomial, over max_record_mb={max_record_mb:g}")
    model = make_integrator(integrator, max_depth=max_depth, **options)
    if model.not_recordable:
        raise ParameterError(f"integrator {model.name!r} cannot be recorded as path records (solver 'lm', identifiability): {model.not_recordable}; fit it with solver 'adam'")
    device = torch.device(device) if device is not None else scene.device
    if isinstance(first_sample, bool) or not isinstance(first_sample, int) or first_sample < 0:
        raise ParameterError(f"record_paths first_sample must be an integer >= 0, got {first_sample!r}")
    plan = SamplePlan(torch.full((w * h,), spp, dtype=torch.int64), torch.full((w * h,), first_sample, dtype=torch.int64)) if first_sample else None
    settings = RenderSettings(spp=spp, seed=seed, memory_mb=memory_mb, progress=progress, sampler=sampler, plan=plan)
    record = torch.cat([scene.params[n].detach().to(device, torch.float64).reshape(-1, 3) for n in names])  # (N_var, 3)
    place = [math.prod(radix[:p]) for p in range(len(radix))]
    material_of = scene.triangles.material.to(device)
    films: dict[int, _RecordFilm] = {}

    coded = None if slots else _fused_places(scene, model, settings, device, names, place)
    with fwAD.dual_level(), torch.no_grad():
        if coded is None:
            duals = {n: fwAD.make_dual(scene.params[n].detach().to(device), scene.params[n].detach().to(device) * place[p]) for p, n in enumerate(names)}
            ctx = model.context(scene, settings, device, params=duals)
        else:  # the fused bounce codes each contribution's monomial itself
            ctx = model.context(scene, settings, device)
        slots = [_with_lookup(s, ctx.lights) if s.lookup is not None else s for s in slots]

        def work(worker: int, state, xy) -> None:
            if worker not in films:
                films[worker] = _RecordFilm(w, h, device, radix, record, slots, material_of, max_depth + 1, max_record_mb * 2**20)
                films[worker].fused_places = coded
            film = films[worker]
            footprint = None if scene.film.is_box else scene.film.filter.footprint(xy, w, h)
            model.trace(ctx, state.replace(pixel=film.begin(state.pixel, footprint)), film)

        for_each_chunk(scene, settings, device, work, grad=False, with_positions=True)

    sums: dict[int, torch.Tensor] = {}
    for film in films.values():
        for code, img in film.sums.items():
            sums[code] = sums[code] + img if code in sums else img
    codes = sorted(sums)
    if len(codes) * 8 * w * h * 3 > max_record_mb * 2**20:
        raise ParameterError(f"the record holds {len(codes)} monomials, {len(codes) * 8 * w * h * 3 / 2**20:.0f} MiB, over max_record_mb={max_record_mb:g}")

    def exponents_of(code_list) -> torch.Tensor:
        return torch.tensor([[(c // pl) % r for pl, r in zip(place, radix)] for c in code_list], dtype=torch.int64).reshape(len(code_list), len(names))

    exponents = exponents_of(codes)
    coefficients = (torch.stack([sums[c] for c in codes]) if codes else torch.zeros(0, w * h * 3, dtype=torch.float64)).reshape(len(codes), w * h, 3)
    if scene.film.is_box:
        coefficients = coefficients / spp
    else:  # the film's normalization: each pixel divided by the sum of the weights it received
        weights = film_weights(scene, settings, device)
        coefficients = coefficients / weights.masked_fill(weights == 0, 1.0)[:, None]
    texel_exponents, texel_terms = None, ()
    if slots:
        tables: dict[int, list] = {}
        for film in films.values():
            for K, part in film.texel_tables().items():
                tables.setdefault(K, []).append(part)
        bound = films[next(iter(films))].bound
        merged = {K: _sum_rows(torch.cat([k for k, _ in parts]), torch.cat([c for _, c in parts]), bound) for K, parts in sorted(tables.items())}
        all_codes = torch.cat([keys[:, 1] for keys, _ in merged.values()]) if merged else torch.zeros(0, dtype=torch.int64)
        term_codes, term = torch.unique(all_codes, return_inverse=True)
        texel_exponents = exponents_of(term_codes.tolist())
        texel_exponents[:, [s.p for s in slots]] = 0
        groups, at = [], 0
        for K, (keys, coef) in merged.items():
            groups.append(TexelTerms(keys[:, 0].clone(), term[at : at + keys.shape[0]].to(device), keys[:, 2:].clone(), coef / spp))
            at += keys.shape[0]
        texel_terms = tuple(groups)
    record_values = {n: scene.params[n].detach().to(device, torch.float64).clone() for n in names}
    return PathRecords(tuple(names), exponents, coefficients, (w, h), record_values, spp, seed, texel_exponents, texel_terms)


def accumulate(records: list[PathRecords]) -> PathRecords:
    """The record of all the samples of ``records`` (records of the same parameters and view,
    traced at any record points, e.g. passes of :func:`record_paths` over disjoint sample ranges
    or with different seeds): each is an unbiased estimate of the image's polynomial, so their
    spp-weighted mean of coefficients is one too, monomial by monomial (a monomial one record
    lacks has coefficient 0 there). ``record_values`` and ``seed`` are the last record's, ``spp``
    the sum."""
    if not records:
        raise ParameterError("accumulate needs at least one record")
    last = records[-1]
    for r in records:
        if r.names != last.names or r.resolution != last.resolution or [v.shape for v in r.record_values.values()] != [v.shape for v in last.record_values.values()]:
            raise ParameterError(f"cannot accumulate records of {', '.join(r.names)} at {r.resolution} with records of {', '.join(last.names)} at {last.resolution}")
    if len(records) == 1:
        return last
    total = sum(r.spp for r in records)
    share = [r.spp / total for r in records]
    exponents, inverse = torch.unique(torch.cat([r.exponents for r in records]), dim=0, return_inverse=True)
    coefficients = last.coefficients.new_zeros(exponents.shape[0], *last.coefficients.shape[1:])
    at = 0
    for r, f in zip(records, share):
        coefficients.index_add_(0, inverse[at : at + r.exponents.shape[0]].to(coefficients.device), r.coefficients * f)
        at += r.exponents.shape[0]
    texel_exponents, texel_terms = last.texel_exponents, last.texel_terms
    if any(r.texel_terms for r in records):
        parts = [r for r in records if r.texel_exponents is not None]
        texel_exponents, term_of = torch.unique(torch.cat([r.texel_exponents for r in parts]), dim=0, return_inverse=True)
        maps, at = {}, 0
        for r in parts:
            maps[id(r)] = term_of[at : at + r.texel_exponents.shape[0]]
            at += r.texel_exponents.shape[0]
        bound = max(last.resolution[0] * last.resolution[1], texel_exponents.shape[0], last.offsets[-1]) + 1
        groups = []
        for K in sorted({g.texels.shape[1] for r in records for g in r.texel_terms}):
            keys, coef = [], []
            for r, f in zip(records, share):
                for g in r.texel_terms:
                    if g.texels.shape[1] == K:
                        keys.append(torch.cat([g.pixel[:, None], maps[id(r)].to(g.term.device)[g.term][:, None], g.texels], dim=1))
                        coef.append(g.coefficients * f)
            unique, summed = _sum_rows(torch.cat(keys), torch.cat(coef), bound)
            groups.append(TexelTerms(unique[:, 0].clone(), unique[:, 1].clone(), unique[:, 2:].clone(), summed))
        texel_terms = tuple(groups)
    return PathRecords(last.names, exponents, coefficients, last.resolution, last.record_values, total, last.seed, texel_exponents, texel_terms)
