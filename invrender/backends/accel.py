"""Ray-triangle intersection backends (geometry is never differentiated:
docs/architecture.md#geometry-is-never-differentiated).

A backend answers two queries for a batch of rays and returns plain, non-differentiable tensors:
``intersect`` (closest hit: distance, triangle id, barycentrics) and ``occluded`` (any hit before a
given distance; False, and not traced, where that distance is not positive). The backends give the
same answers up to float rounding:

- ``embree``: Intel Embree on the CPU (the fast default there), packets of 16 rays (8 with AVX2) through the compiled
  wrapper of :mod:`~invrender.backends.embree_native` (embreex's single rays where it does not
  build), rays split across threads;
- ``warp``: NVIDIA Warp's BVH (:mod:`invrender.backends.warp_bvh`), on CUDA (the default there)
  and on the CPU, rays and results shared with torch without copies;
- ``torch``: Moller-Trumbore against every triangle in blocks sized to a memory budget, on any
  device: the reference (fine for scenes of up to a few thousand triangles), and the default where
  the default backend's package (embreex, warp-lang) is not installed.

Barycentrics follow Embree: the hit point is ``p0 + u e1 + v e2``.

Rays that cannot be traced are misses, on every backend: a ray with a component of its origin or
direction that is NaN, infinite or larger in magnitude than :data:`RAY_LIMIT` has no closest hit
(``t = inf``, ``prim = -1``) and is not occluded. :class:`Intersector`, the base of every backend,
answers them before the backend's own query sees them, unless the backend checks its lanes itself
(Embree's packet wrapper and Warp's kernels do, at no cost). Embree built with assertions, as
Debian's Embree 3 is, aborts the whole process on such a ray, and Warp reported hits at ``t = 0``
for infinite directions; so a NaN from a parameter, a degenerate triangle or a plugin costs those
paths, not the process. A shadow ray whose distance is not positive (or is NaN) is not traced: not occluded.

Geometry never changes once a scene is built, so :func:`intersector_for` builds each backend's
acceleration structure once per geometry and keeps it with the triangles
(:meth:`~invrender.scene.scene.Triangles.derived`): renders, fit steps and gradient trials of one
scene share it.
"""

from __future__ import annotations

import abc
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch

from invrender.backends.arrays import Columns, stacked, take
from invrender.vec import where_true
from invrender.errors import ParameterError, did_you_mean
from invrender.scene.scene import Triangles
from invrender.backends import embree_native, packages


@dataclass(frozen=True)
class Hits:
    """Closest hits of N rays.

    Attributes:
        t: (N,) float32 distance along the (unit) ray direction; ``inf`` where the ray missed.
        prim: (N,) int64 triangle index; -1 where the ray missed.
        u: (N,) float32 barycentric weight of the triangle's second vertex.
        v: (N,) float32 barycentric weight of the third vertex.
    """

    t: torch.Tensor
    prim: torch.Tensor
    u: torch.Tensor
    v: torch.Tensor

    @property
    def valid(self) -> torch.Tensor:
        """(N,) bool, True where the ray hit something."""
        return self.prim >= 0

    def select(self, mask: torch.Tensor) -> "Hits":
        """The hits where ``mask`` (N,) bool is True, or at ``mask`` (M,) int64."""
        index = mask.nonzero()[:, 0] if mask.dtype == torch.bool else mask
        return Hits(*(x.index_select(0, index) for x in (self.t, self.prim, self.u, self.v)))


@dataclass(frozen=True)
class FoundHits:
    """The closest hits of a batch of N rays compacted to the H rays that hit
    (:meth:`Intersector.closest_hits`).

    Attributes:
        index: (H,) int64 the rays that hit, in order.
        t, prim, u, v: (H,) their hits (:class:`Hits`, all valid).
        gone: (N - H,) int64 the rays that missed, in order; None unless asked for.
    """

    index: torch.Tensor
    t: torch.Tensor
    prim: torch.Tensor
    u: torch.Tensor
    v: torch.Tensor
    gone: torch.Tensor | None


def compacted_hits(intersect, o, d, misses: bool = False, alive: torch.Tensor | None = None) -> FoundHits:
    """:meth:`Intersector.closest_hits` through ``intersect`` (a closest-hit query): the rays
    ``alive`` picks (all without it) asked, then their hits compacted."""
    live = None if alive is None else where_true(alive)
    if live is not None:
        o, d = take(o, live), take(d, live)
    hits = intersect(o, d)
    index = where_true(hits.valid)
    gone = where_true(~hits.valid) if misses else None
    t, prim, u, v = (x.index_select(0, index) for x in (hits.t, hits.prim, hits.u, hits.v))
    if live is not None:  # back to the positions among all the rays
        index = live.index_select(0, index)
        gone = None if gone is None else live.index_select(0, gone)
    return FoundHits(index, t, prim, u, v, gone)


#: the largest magnitude of a ray's origin or direction components that is traced: Embree's
#: ``FLT_LARGE`` (its ``RayK::valid``), mirrored in ``embree_packets.cpp``; rays beyond it are misses
RAY_LIMIT = 1.844e18


def traceable(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """(N,) bool: True where every component of origin ``o`` (N, 3) and direction ``d`` (N, 3) is
    finite and at most :data:`RAY_LIMIT` in magnitude (False for NaN: the comparison fails)."""
    return (o.abs() <= RAY_LIMIT).all(1) & (d.abs() <= RAY_LIMIT).all(1)


def _untraceable_lanes(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor | None:
    """None when every ray of ``o``, ``d`` (N, 3) is traceable, else :func:`traceable`'s (N,) mask.

    On the CPU one dot product a tensor says so (about 1 ns a ray, 1-2% of an Embree query): the
    sum of squares is at most ``RAY_LIMIT**2`` only when every component is finite and within the
    limit (NaN compares false; a sum that overflows only sends the batch to the exact test). On
    other devices that answer would wait for the device, so the mask is always computed and applied
    there (elementwise, no synchronization)."""
    if o.device.type == "cpu":
        a, b = o.reshape(-1), d.reshape(-1)
        if bool(torch.dot(a, a) + torch.dot(b, b) <= RAY_LIMIT**2):
            return None
    return traceable(o, d)


def _stand_ins(o: torch.Tensor, d: torch.Tensor, ok: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``o``, ``d`` with the rays where ``ok`` (N,) is False replaced by a finite one (from the
    world origin along +z), whose answer is then discarded."""
    return torch.where(ok[:, None], o, 0.0), torch.where(ok[:, None], d, d.new_tensor((0.0, 0.0, 1.0)))


class Intersector(abc.ABC):
    """The base of every backend: the two queries, with untraceable rays (:func:`traceable`)
    answered as misses before the backend's own ``_intersect`` / ``_occluded`` is asked, so no
    backend can be handed one unless it says it checks its rays itself.

    Attributes:
        name: the backend's name.
        checks_rays: True where the backend's own queries answer untraceable rays as misses in
            the lanes that trace them (Embree's packets, Warp's kernels), where the check costs
            nothing, while this class's costs a pass over the rays and, off the CPU, elementwise
            masking (a render of the Cornell box spent 6% of its time in it with Embree's
            packets). The test of every backend (tests/transport/test_nonfinite.py) holds those
            that say so to it.
    """

    name = ""
    checks_rays = False
    #: its queries read rays given as :class:`~invrender.backends.arrays.Columns` as they are (the
    #: others get them stacked)
    takes_columns = False

    def intersect(self, o: torch.Tensor, d: torch.Tensor) -> Hits:
        """Closest hits of rays with origins ``o`` (N, 3) and unit directions ``d`` (N, 3) (or
        :class:`~invrender.backends.arrays.Columns`); a miss (``t = inf``, ``prim = -1``, ``u =
        v = 0``) where the ray cannot be traced."""
        if not self.takes_columns:
            o, d = stacked(o), stacked(d)
        ok = None if self.checks_rays else _untraceable_lanes(o, d)
        if ok is None:
            return self._intersect(o, d)
        hits = self._intersect(*_stand_ins(o, d, ok))
        miss = ~ok.to(hits.t.device)
        return Hits(hits.t.masked_fill(miss, math.inf), hits.prim.masked_fill(miss, -1), hits.u.masked_fill(miss, 0.0), hits.v.masked_fill(miss, 0.0))

    def closest_hits(self, o: torch.Tensor, d: torch.Tensor, misses: bool = False, alive: torch.Tensor | None = None) -> FoundHits:
        """:meth:`intersect`'s answers compacted to the rays that hit (and, with ``misses``, the
        rays that missed): a synchronization, their count. With ``alive`` (N,) bool, only the rays
        where it is True are traced (the others, paths that ended, neither hit nor miss): a caller
        need not compact its paths first. A backend that can compacts as it answers (Embree's
        packets: no pass over the answers of its own)."""
        return compacted_hits(self.intersect, o, d, misses, alive)

    def records(self, kind: str) -> bool:
        """Are the queries of ``kind`` recorded, to be answered again in order (a backend: never;
        :class:`RepeatedQueries`: its kinds)? A caller then asks exactly the queries the torch
        bounce asks."""
        return False

    def occluded(self, o: torch.Tensor, d: torch.Tensor, tmax: torch.Tensor) -> torch.Tensor:
        """(N,) bool: does anything lie along each ray strictly before ``tmax`` (N,)? False where
        ``tmax`` is not positive or NaN (not traced) and where the ray cannot be traced."""
        if not self.takes_columns:
            o, d = stacked(o), stacked(d)
        ok = None if self.checks_rays else _untraceable_lanes(o, d)
        if ok is None:
            return self._occluded(o, d, tmax)
        o, d = _stand_ins(o, d, ok)
        return self._occluded(o, d, torch.where(ok, tmax, 0.0)) & ok.to(tmax.device)

    @abc.abstractmethod
    def _intersect(self, o: torch.Tensor, d: torch.Tensor) -> Hits:
        """The backend's closest-hit query on rays it can trace (:meth:`intersect`'s shapes)."""

    @abc.abstractmethod
    def _occluded(self, o: torch.Tensor, d: torch.Tensor, tmax: torch.Tensor) -> torch.Tensor:
        """The backend's shadow query on rays it can trace (:meth:`occluded`'s shapes)."""


class EmbreeIntersector(Intersector):
    """Intel Embree on the CPU: packets of 16 rays (8 with AVX2) through the compiled wrapper of
    :mod:`~invrender.backends.embree_native` where it builds, else embreex's single rays (the same
    answers up to float rounding); each batch split across threads, results moved to the rays' device."""

    name = "embree"

    def __init__(self, triangles: Triangles, threads: int | None = None):
        lib, why = embree_native.library() if embree_native.mode() == "packets" else (None, "")
        self._packets = self._scene = None
        if lib is not None:
            self._packets = embree_native.PacketScene(lib, triangles.corners())
            self.checks_rays = True  # the wrapper's lanes (embree_packets.cpp: traceable)
            self.takes_columns = True  # a pointer per component (embree_native._strided)
        else:
            packages.require("embreex", "the embree intersection backend", f"{embree_native.INSTALL_HINT} for Embree's packets, or use backend 'torch'")
            if why:
                packages.note_once(f"the embree backend traces single rays through embreex: {why} ({embree_native.INSTALL_HINT} for Embree's packets)")
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh

            self._scene = rtcore_scene.EmbreeScene()
            corners = triangles.corners().detach().cpu().numpy().astype(np.float32)
            self._mesh = TriangleMesh(self._scene, corners)  # keep a reference: Embree does not own the buffer
        self._threads = embree_threads(threads)
        self._pool = ThreadPoolExecutor(self._threads) if self._threads > 1 else None

    @property
    def packets(self) -> bool:
        """True when queries go through Embree's packets, False for embreex's single rays."""
        return self._packets is not None

    def _split(self, n: int, job) -> list:
        """``job(a, b)`` over a split of ``range(n)`` across threads (Embree runs without the GIL)."""
        if self._pool is None or n < 4096:
            return [job(0, n)]
        bounds = np.linspace(0, n, self._threads + 1).astype(int)
        return [f.result() for f in [self._pool.submit(job, a, b) for a, b in zip(bounds[:-1], bounds[1:])]]

    def _intersect(self, o: torch.Tensor, d: torch.Tensor) -> Hits:
        if self._packets is not None:
            n, dev = _lanes(o), _device(o)
            o, d = _cpu32(o, rows=False), _cpu32(d, rows=False)
            out = (torch.empty(n), torch.empty(n, dtype=torch.int64), torch.empty(n), torch.empty(n))
            self._split(n, lambda a, b: self._packets.intersect(_rows(o, a, b), _rows(d, a, b), tuple(x[a:b] for x in out)))
            return Hits(*(x.to(dev) for x in out))
        n, dev = o.shape[0], o.device
        o, d = _numpy(o), _numpy(d)
        parts = self._split(n, lambda a, b: self._scene.run(o[a:b], d[a:b], output=1))

        def joined(key: str) -> torch.Tensor:  # Embree's arrays, shared (no copy for one part)
            return torch.from_numpy(parts[0][key] if len(parts) == 1 else np.concatenate([p[key] for p in parts]))

        miss = joined("geomID") < 0
        prim = joined("primID").long().masked_fill_(miss, -1)
        t = joined("tfar").masked_fill_(miss, math.inf)
        return Hits(*(a.to(dev) for a in (t, prim, joined("u"), joined("v"))))

    def closest_hits(self, o: torch.Tensor, d: torch.Tensor, misses: bool = False, alive: torch.Tensor | None = None) -> FoundHits:
        if self._packets is None:
            return super().closest_hits(o, d, misses, alive)
        n, dev = _lanes(o), _device(o)
        o, d = _cpu32(o, rows=False), _cpu32(d, rows=False)
        alive = None if alive is None else alive.to("cpu").contiguous()
        out = (torch.empty(n, dtype=torch.int64), torch.empty(n), torch.empty(n, dtype=torch.int64), torch.empty(n), torch.empty(n))
        gone = torch.empty(n, dtype=torch.int64) if misses else None
        # each thread's part compacted at the start of its rows: (start, hits, misses)
        parts = self._split(n, lambda a, b: (a, *self._packets.hits(_rows(o, a, b), _rows(d, a, b), tuple(x[a:b] for x in out), None if gone is None else gone[a:b], None if alive is None else alive[a:b])))
        if len(parts) == 1:
            found = [x[: parts[0][1]] for x in out]
            missed = None if gone is None else gone[: parts[0][2]]
        else:  # (a part's rays counted from its start)
            found = [torch.cat([out[0][a : a + h] + a for a, h, _ in parts])] + [torch.cat([x[a : a + h] for a, h, _ in parts]) for x in out[1:]]
            missed = None if gone is None else torch.cat([gone[a : a + m] + a for a, _, m in parts])
        if dev.type != "cpu":
            found = [x.to(dev) for x in found]
            missed = None if missed is None else missed.to(dev)
        return FoundHits(*found, missed)

    def _occluded(self, o: torch.Tensor, d: torch.Tensor, tmax: torch.Tensor) -> torch.Tensor:
        if self._packets is not None:
            n, dev = _lanes(o), _device(o)
            o, d, tmax = _cpu32(o, rows=False), _cpu32(d, rows=False), _cpu32(tmax)
            hit = torch.empty(n, dtype=torch.bool)
            self._split(n, lambda a, b: self._packets.occluded(_rows(o, a, b), _rows(d, a, b), tmax[a:b], hit[a:b]))
            return hit.to(dev)
        n, dev = o.shape[0], o.device
        o, d, tmax = _numpy(o), _numpy(d), _numpy(tmax)
        parts = self._split(n, lambda a, b: self._scene.run(o[a:b], d[a:b], dists=tmax[a:b], query="OCCLUDED"))
        hit = torch.from_numpy(parts[0] if len(parts) == 1 else np.concatenate(parts)) != -1
        return (hit & torch.from_numpy(tmax > 0)).to(dev)


class WarpIntersector(Intersector):
    """NVIDIA Warp's BVH on the triangles' device (CUDA or CPU); rays must be on that device."""

    name = "warp"
    checks_rays = True  # its kernels (warp_bvh.traceable)

    def __init__(self, triangles: Triangles):
        from invrender.backends.warp_bvh import WarpBVH

        self._bvh = WarpBVH(triangles.corners())

    def _intersect(self, o: torch.Tensor, d: torch.Tensor) -> Hits:
        return Hits(*self._bvh.closest(o, d))

    def _occluded(self, o: torch.Tensor, d: torch.Tensor, tmax: torch.Tensor) -> torch.Tensor:
        return self._bvh.occluded(o, d, tmax)


class TorchIntersector(Intersector):
    """Brute-force Moller-Trumbore in torch, on any device, blocked to bound memory."""

    name = "torch"

    def __init__(self, triangles: Triangles, block_elements: int = 1 << 22):
        self.p0, self.e1, self.e2 = triangles.p0, triangles.e1, triangles.e2
        self.block_elements = block_elements

    def _closest(self, o: torch.Tensor, d: torch.Tensor, tmax: torch.Tensor | None):
        n, count = o.shape[0], self.p0.shape[0]
        t_best = torch.full((n,), math.inf, device=o.device)
        prim = torch.full((n,), -1, dtype=torch.int64, device=o.device)
        u_best = torch.zeros(n, device=o.device)
        v_best = torch.zeros(n, device=o.device)
        tri_block = max(1, min(count, self.block_elements // 64))
        ray_block = max(1, self.block_elements // tri_block)
        for r0 in range(0, n, ray_block):
            rs = slice(r0, min(n, r0 + ray_block))
            ro, rd = o[rs, None, :], d[rs, None, :]
            for t0 in range(0, count, tri_block):
                ts = slice(t0, min(count, t0 + tri_block))
                p0, e1, e2 = self.p0[None, ts], self.e1[None, ts], self.e2[None, ts]
                pvec = torch.linalg.cross(rd.expand(-1, e2.shape[1], -1), e2.expand(rd.shape[0], -1, -1))
                det = (e1 * pvec).sum(-1)
                inv = 1.0 / det
                tvec = ro - p0
                u = (tvec * pvec).sum(-1) * inv
                qvec = torch.linalg.cross(tvec, e1.expand_as(tvec))
                v = (rd * qvec).sum(-1) * inv
                t = (e2 * qvec).sum(-1) * inv
                ok = (det.abs() > 1e-20) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
                if tmax is not None:
                    ok &= t < tmax[rs, None]
                t = torch.where(ok, t, math.inf)
                tmin, arg = t.min(dim=1)
                better = tmin < t_best[rs]
                t_best[rs] = torch.where(better, tmin, t_best[rs])
                prim[rs] = torch.where(better, arg + t0, prim[rs])
                u_best[rs] = torch.where(better, u.gather(1, arg[:, None])[:, 0], u_best[rs])
                v_best[rs] = torch.where(better, v.gather(1, arg[:, None])[:, 0], v_best[rs])
        return Hits(t_best, prim, u_best, v_best)

    def _intersect(self, o: torch.Tensor, d: torch.Tensor) -> Hits:
        return self._closest(o, d, None)

    def _occluded(self, o: torch.Tensor, d: torch.Tensor, tmax: torch.Tensor) -> torch.Tensor:
        return self._closest(o, d, tmax).valid


BACKENDS = {"embree": EmbreeIntersector, "warp": WarpIntersector, "torch": TorchIntersector}


#: the package each backend needs (torch needs none; embree needs embreex only where its packets do not build)
PACKAGES = {"embree": "embreex", "warp": "warp"}


def missing(backend: str) -> str | None:
    """Why ``backend`` cannot run in this process (its package is not installed: a sentence with its
    install command), or None when it can."""
    if backend == "embree" and embree_native.mode() == "packets" and embree_native.library()[0] is not None:
        return None
    module = PACKAGES.get(backend)
    if module is None or packages.find(module) is not None:
        return None
    return f"{packages.PIP_NAMES[module]} is not installed ({packages.install_hint(module)})"


def default_backend(device: torch.device) -> str:
    """``embree`` on the CPU, ``warp`` elsewhere (CUDA); ``torch`` when that backend cannot run
    (:func:`missing`), said once on stderr."""
    backend = "embree" if torch.device(device).type == "cpu" else "warp"
    if missing(backend) is not None:
        module = PACKAGES[backend]
        packages.note_once(
            f"{packages.PIP_NAMES[module]} is not installed: intersecting with the torch backend, not {backend} ({packages.install_hint(module)} for {backend})"
        )
        return "torch"
    return backend


def check_backend(backend: str | None, device: torch.device) -> str:
    """The backend name to use on ``device`` (``None`` = the device's default); a one-line
    :class:`ParameterError` for an unknown name or one that cannot run there (Embree: CPU only)."""
    backend = backend or default_backend(device)
    if backend not in BACKENDS:
        raise ParameterError(f"unknown intersection backend {backend!r}{did_you_mean(backend, BACKENDS)} (known: {', '.join(BACKENDS)})")
    if backend == "embree" and torch.device(device).type != "cpu":
        raise ParameterError(f"the embree backend runs on the CPU only, not on {device}: use backend 'warp' or 'torch'")
    return backend


def make_intersector(triangles: Triangles, backend: str | None = None, threads: int | None = None):
    """A new intersector for ``triangles`` by backend name (``None`` = the device's default).

    ``threads``: threads each Embree query is split across (None = one per core).
    """
    backend = check_backend(backend, triangles.p0.device)
    cls = BACKENDS[backend]
    return EmbreeIntersector(triangles, threads) if cls is EmbreeIntersector else cls(triangles)


def embree_threads(threads: int | None) -> int:
    """Threads an Embree query is split across: ``threads``, or one per core when None."""
    return max(1, threads or len(os.sched_getaffinity(0)))


def intersector_for(triangles: Triangles, backend: str | None = None, threads: int | None = None):
    """The intersector of ``triangles`` for a backend, built on first use and kept with the
    geometry (:meth:`Triangles.derived`), so that renders of one scene share it."""
    backend = check_backend(backend, triangles.p0.device)
    threads = embree_threads(threads) if backend == "embree" else None
    queries = embree_native.mode() if backend == "embree" else None
    return triangles.derived(("accel", backend, threads, queries), lambda: make_intersector(triangles, backend, threads))


def _numpy(x: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(x.detach().to("cpu", torch.float32).numpy())


def _cpu32(x, rows: bool = True):
    """``x`` as float32 on the CPU, contiguous, or (``rows=False``: for Embree's packet wrapper,
    which reads (N, 3) rays through their strides, or :class:`Columns` each contiguous) in
    whatever layout it has."""
    if isinstance(x, Columns):
        return Columns(c.detach().to("cpu", torch.float32).contiguous() for c in x)
    x = x.detach().to("cpu", torch.float32)
    return x.contiguous() if rows else x


def _lanes(x) -> int:
    return x.lanes if isinstance(x, Columns) else x.shape[0]


def _device(x) -> torch.device:
    return x[0].device if isinstance(x, Columns) else x.device


def _rows(x, a: int, b: int):
    return x.rows(a, b) if isinstance(x, Columns) else x[a:b]


class QueriesDiverged(RuntimeError):
    """A repeated trace asked another query than its first trace had at that point."""


class RepeatedQueries:
    """An intersector that answers one trace's queries and then the same trace's again, from memory.

    Path replay's adjoint pass casts exactly the rays its primal pass cast, in the same order (same
    random numbers, the throughput detached but equal): the first trace asks the backend and keeps
    each answer of the ``kinds`` it records, :meth:`repeat` switches to handing them back, so the
    second trace asks the backend only for the kinds not recorded. Closest hits cost about 20 bytes
    a ray; shadow-ray answers are kept as bits (the forward pass that keeps per-path radiance for
    replay keeps these for the whole image). A recorded query whose batch size differs from the
    one at that point in the first trace is an error (the passes diverged).
    """

    def __init__(self, backend, kinds: tuple[str, ...] = ("intersect", "occluded")):
        self.name = backend.name
        self._backend, self._kinds, self._answers, self._next = backend, kinds, [], None

    def records(self, kind: str) -> bool:
        return kind in self._kinds

    def repeat(self, backend=None) -> RepeatedQueries:
        """From now on, answer the recorded queries in order (the others from ``backend``, default
        the first trace's); returns self."""
        self._backend = backend or self._backend
        self._next = 0
        return self

    def _answer(self, kind: str, n: int, ask):
        if kind not in self._kinds:
            return ask()
        if self._next is None:
            answer = ask()
            self._answers.append((kind, n, _pack_bits(answer) if kind == "occluded" else answer))
            return answer
        recorded_kind, size, answer = self._answers[self._next]
        if recorded_kind != kind or size != n:
            raise QueriesDiverged(
                f"path replay: the adjoint pass's query {self._next} ({kind} of {n} rays) differs from its primal pass's ({recorded_kind} of {size})"
            )
        self._answers[self._next] = None  # each answer is handed back once
        self._next += 1
        return _unpack_bits(answer, n) if kind == "occluded" else answer

    def intersect(self, o: torch.Tensor, d: torch.Tensor) -> Hits:
        return self._answer("intersect", _lanes(o), lambda: self._backend.intersect(o, d))

    def occluded(self, o: torch.Tensor, d: torch.Tensor, tmax: torch.Tensor) -> torch.Tensor:
        return self._answer("occluded", _lanes(o), lambda: self._backend.occluded(o, d, tmax))

    def closest_hits(self, o: torch.Tensor, d: torch.Tensor, misses: bool = False, alive: torch.Tensor | None = None) -> FoundHits:
        """(Recorded as the closest-hit query of the ``alive`` rays it compacts, as the torch
        bounce asks it: the other pass may ask either.)"""
        return compacted_hits(self.intersect, o, d, misses, alive)


def _bit_weights(device) -> torch.Tensor:
    return torch.tensor([1, 2, 4, 8, 16, 32, 64, 128], dtype=torch.uint8, device=device)


def _pack_bits(mask: torch.Tensor) -> torch.Tensor:
    """(n,) bool -> (ceil(n / 8),) uint8, bit j of byte i = mask[8 i + j]."""
    n = mask.shape[0]
    padded = torch.zeros(-(-n // 8) * 8, dtype=torch.uint8, device=mask.device)
    padded[:n] = mask
    return (padded.view(-1, 8) * _bit_weights(mask.device)).sum(1, dtype=torch.uint8)  # disjoint bits: no carries


def _unpack_bits(packed: torch.Tensor, n: int) -> torch.Tensor:
    """The (n,) bool mask of :func:`_pack_bits`."""
    return (packed[:, None] & _bit_weights(packed.device)).ne(0).view(-1)[:n]
