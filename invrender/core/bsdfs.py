"""The BSDF interface and the dispatch of a batch of hits to the scene's materials.

Each material type is a :class:`~.base.BSDF` subclass registered in
:data:`invrender.registry.MATERIALS` (the built-in ones in :mod:`invrender.plugins.bsdfs`). A render
builds one instance per type present in the scene (holding all materials of that type), and
:class:`Materials` sends each hit to its type's instance: one batched call per type and bounce,
so a scene with one material type pays no dispatch at all. Integrators ask :meth:`Materials.has`
which kinds of lobe (:class:`~.base.Lobe`) a hit's BSDF has, never which type it is.
"""

from __future__ import annotations

import torch

from invrender.registry import MATERIALS
from invrender.core.bsdf import BSDF, HEMISPHERES, BSDFSample, BSDFSampling, DeltaBSDF, Lobe, ShadingPoint


class Materials:
    """The scene's BSDFs on one device, and per-hit dispatch to them.

    Args:
        types: per scene material, its type name.
        values: per scene material, parameter key -> tensor (differentiable).
        constants: per scene material, constant key -> float.
        device: where hits live.
        flat: the scene has no shading normals (BSDFs may skip checks that only they need).
        sampling: how the BSDFs draw directions (default: cosine-weighted diffuse lobes).
        sampling_values: per scene material, the values its sampling reads (detached; None = its
            own ``values``, detached).
        texture_sampling: per scene material, parameter key -> how its texture is read
            (:class:`~invrender.scene.textures.TextureSampling`); None = the defaults.
        one_sided: per scene material, is its back side black (``Material.one_sided``: Mitsuba's
            BSDFs without ``twosided``)? None = every material two-sided. Ignored for types that
            transmit.
        perturbations: per scene material, its normal or bump map
            (:class:`~invrender.scene.materials.NormalPerturbation`) or None; None = none.
        sampling_perturbations: the same, as sampling reads them where a render holds sampling
            at other normal maps (``sampling_params``); None = ``perturbations``.
    """

    def __init__(
        self, types: list[str], values: list[dict[str, torch.Tensor]], constants: list[dict[str, float]], device, flat: bool = False, sampling: BSDFSampling | None = None,
        sampling_values: list[dict[str, torch.Tensor]] | None = None, one_sided: list[bool] | None = None, texture_sampling: list[dict] | None = None,
        perturbations: list | None = None, sampling_perturbations: list | None = None,
    ):  # fmt: skip
        #: per scene material, its normal perturbation or None (:mod:`invrender.core.shading`)
        self.perturbations = list(perturbations) if perturbations is not None and any(p is not None for p in perturbations) else None
        #: per scene material, the perturbation sampling reads where a render holds it elsewhere; None = the same
        self.sampling_perturbations = None if self.perturbations is None or sampling_perturbations is None else list(sampling_perturbations)
        present = list(dict.fromkeys(types))  # first-seen order
        self.bsdfs: list[BSDF] = []
        slot_of, local_of = [], []
        for t in present:
            members = [i for i, ti in enumerate(types) if ti == t]
            frozen = None if sampling_values is None else [sampling_values[i] for i in members]
            textures = None if texture_sampling is None else [texture_sampling[i] for i in members]
            self.bsdfs.append(MATERIALS[t]([values[i] for i in members], [constants[i] for i in members], flat, sampling, frozen, textures))
        for t in types:
            k = present.index(t)
            slot_of.append(k)
            local_of.append(sum(1 for ti in types[: len(local_of)] if ti == t))
        #: (M,) which of ``bsdfs`` each scene material uses, and its index among that BSDF's materials
        self.slot_of = torch.tensor(slot_of, dtype=torch.int64, device=device)
        self.local_of = torch.tensor(local_of, dtype=torch.int64, device=device)
        self.single = len(self.bsdfs) == 1
        #: (K,) int64 each BSDF slot's lobe flags (for :meth:`has`)
        self._lobe_table = torch.tensor([int(b.lobes) for b in self.bsdfs], dtype=torch.int64, device=device)
        #: some BSDF has no smooth lobe (delta only): next-event estimation skips its hits
        self.any_delta_only = any(not b.has(Lobe.SMOOTH) for b in self.bsdfs)
        #: some BSDF transmits through a lobe with a density: next-event estimation looks behind its hits too
        self.any_smooth_transmission = any(b.has(Lobe.GLOSSY_TRANSMISSION) for b in self.bsdfs)
        #: every BSDF is purely Lambertian (its sample weight is rho, never zero on a flat scene)
        self.all_diffuse = all(b.lobes == Lobe.DIFFUSE for b in self.bsdfs)
        if self.perturbations is not None:  # perturbed normals: not a flat scene, weights can be zero (a light between the normals)
            self.all_diffuse = False
            for b in self.bsdfs:
                b.flat = False
        #: (K, L) bool: is material l of BSDF slot k one-sided (black from behind)? None: none is
        self._one_sided = None
        if one_sided is not None and any(one_sided):
            table = torch.zeros(len(self.bsdfs), max(local_of) + 1, dtype=torch.bool)
            for m, flag in enumerate(one_sided):
                table[slot_of[m], local_of[m]] = bool(flag) and not self.bsdfs[slot_of[m]].has(Lobe.TRANSMISSION)
            if bool(table.any()):
                self._one_sided = table.to(device)
                self.all_diffuse = False  # a back-side hit's weight is zero

    def shading_point(self, material: torch.Tensor, wo, n, ng, front, uv, corners=None, bary=None, frame=None, bend=None) -> ShadingPoint:
        """The :class:`ShadingPoint` of hits on scene materials ``material`` (N,) int64 (``corners``
        and ``bary``: for per-vertex parameters, see :class:`ShadingPoint`; ``frame``: the shading
        frames where they are not the default's, with ``bend``: :mod:`invrender.core.shading`)."""
        vertex = {} if corners is None else {"corners": corners, "bary": bary}
        if bend is not None:
            vertex["bend"] = bend
        if self.single:  # local index = scene index; no dispatch
            sp = ShadingPoint(wo, n, ng, front, uv, material, torch.zeros_like(material), **vertex)
        else:
            sp = ShadingPoint(wo, n, ng, front, uv, self.local_of[material], self.slot_of[material], **vertex)
        if frame is not None:
            sp.__dict__["frame"] = frame
        return sp

    def groups(self, sp: ShadingPoint) -> list[tuple[BSDF, torch.Tensor | None]]:
        """``[(bsdf, index of its hits)]``; the index is None when one BSDF takes every hit."""
        if self.single:
            return [(self.bsdfs[0], None)]
        slot = sp.slot
        out = []
        for k, bsdf in enumerate(self.bsdfs):
            index = (slot == k).nonzero()[:, 0]
            if index.numel():
                out.append((bsdf, index))
        return out

    def has_rows(self, lobes: Lobe) -> torch.Tensor:
        """(M,) bool: does each scene material's BSDF have any of ``lobes``?"""
        return (self._lobe_table.index_select(0, self.slot_of) & int(lobes)) != 0

    def has(self, sp: ShadingPoint, lobes: Lobe) -> torch.Tensor:
        """(N,) bool: does each point's BSDF have any of ``lobes``?"""
        return (self._lobe_table.index_select(0, sp.slot) & int(lobes)) != 0

    def _dispatch(self, sp: ShadingPoint, call):
        groups = self.groups(sp)
        if not groups or groups[0][1] is None:  # one BSDF for every hit (or no hits at all)
            return call(self.bsdfs[0], sp, None)
        out = None
        for bsdf, index in groups:
            part = call(bsdf, sp.select(index), index)
            out = _scatter(_empty_like(part, sp.count) if out is None else out, index, part)
        return out

    def _lit(self, sp: ShadingPoint) -> torch.Tensor | None:
        """(N,) float: 0 where a one-sided material is seen from behind, else 1; None when no
        material is one-sided."""
        if self._one_sided is None:
            return None
        return (~(self._one_sided[sp.slot, sp.material] & ~sp.front)).to(sp.wo.dtype)

    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``f |cos theta_i|`` (N, 3) of each hit's BSDF (0 at the back of a one-sided material;
        masked and weighted where a normal is perturbed: :func:`~invrender.core.lanes.bend_lanes`)."""
        f = self._dispatch(sp, lambda b, p, i: b.eval(p, wi if i is None else wi[i]))
        lit = self._lit(sp)
        f = f if lit is None else f * lit[:, None]
        return f if sp.bend is None else f * _bend(sp, wi)[0][:, None]

    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """Solid-angle pdf (N,) of each hit's BSDF sampling ``wi`` (0 at the back of a one-sided
        material: it samples nothing there), in the frame sampling reads (:attr:`ShadingPoint.sampling`)."""
        sp = sp if sp.sampling is None else sp.sampling
        pdf = self._dispatch(sp, lambda b, p, i: b.pdf(p, wi if i is None else wi[i]))
        lit = self._lit(sp)
        pdf = pdf if lit is None else pdf * lit
        return pdf if sp.bend is None else torch.where(_bend(sp, wi)[1], pdf, 0.0)

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        """One direction per hit from its BSDF (weight and pdf 0 at the back of a one-sided
        material: the path ends there).

        Where the points' shading frame can differ from the one sampling reads (differentiated
        normals: :attr:`ShadingPoint.sampling`), the direction is drawn in the sampling frame, as
        sampling never depends on a differentiated parameter, and the weight of a sample of a lobe
        with a density is ``eval(wi) / pdf``, the pdf the sampling frame's: the same value where
        the frames agree, differentiable in the frame at the fixed world direction ``wi`` (a delta
        lobe's weight is the sampling frame's: its direction would have to turn with the normal,
        which is not followed)."""
        if sp.sampling is not None:
            s = self._sample(sp.sampling, u_lobe, u_dir)
            pdf = s.pdf.detach()
            smooth = (~s.delta & (pdf > 0))[:, None]
            weight = torch.where(smooth, self.eval(sp, s.wi) / torch.where(pdf > 0, pdf, 1.0)[:, None], s.weight)
            return BSDFSample(s.wi.detach(), weight, pdf, s.delta)
        return self._sample(sp, u_lobe, u_dir)

    def _sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        s = self._dispatch(sp, lambda b, p, i: b.sample(p, u_lobe if i is None else u_lobe[i], u_dir if i is None else u_dir[i]))
        lit = self._lit(sp)
        s = s if lit is None else BSDFSample(s.wi, s.weight * lit[:, None], s.pdf * lit, s.delta)
        if sp.bend is None:
            return s
        g, kept = _bend(sp, s.wi)
        return BSDFSample(s.wi, s.weight * g[:, None], torch.where(kept, s.pdf, 0.0), s.delta)

    def one_sided_rows(self) -> torch.Tensor:
        """(M,) bool: is each scene material one-sided (black from behind)?"""
        if self._one_sided is None:
            return torch.zeros_like(self.slot_of, dtype=torch.bool)
        return self._one_sided[self.slot_of, self.local_of]

    def fused_albedo(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Where no material is one-sided or perturbed and some BSDF type gives its table
        (:meth:`BSDF.fused_albedo`): (M, 3) rho per scene material, zeros for the others, and
        (M,) bool whether each one's row is its reflectance (an RGB constant of a type that gives
        its table: a parameter the fused bounce can carry derivatives in; the other materials'
        factors are constants of the paths); else None."""
        if self._one_sided is not None or self.perturbations is not None:
            return None
        tables = [b.fused_albedo() for b in self.bsdfs]
        if all(t is None for t in tables):
            return None
        rho = torch.zeros(self.slot_of.shape[0], 3, device=self.slot_of.device)
        slot = torch.zeros(self.slot_of.shape[0], dtype=torch.bool, device=self.slot_of.device)
        for i, (t, local) in enumerate(zip(self.slot_of.tolist(), self.local_of.tolist())):
            if tables[t] is not None:
                row = tables[t][local]
                rho[i], slot[i] = row.detach(), self._constant(t, local)
        return rho, slot

    def _constant(self, t: int, local: int) -> bool:
        """Is material ``local`` of type ``t``'s reflectance an RGB constant (not a texture)?"""
        value = self.bsdfs[t].values[local].get("reflectance")
        return value is not None and value.ndim == 1

    def diffuse_reflectance(self, sp: ShadingPoint) -> torch.Tensor:
        """k_d (N, 3) of each hit for the ambient term (0 for materials without a diffuse part, and
        at the back of a one-sided material)."""

        def call(b, p, i):
            value = b.diffuse_reflectance(p)
            return value if value is not None else p.wo.new_zeros(p.count, 3)

        kd = self._dispatch(sp, call)
        lit = self._lit(sp)
        return kd if lit is None else kd * lit[:, None]


def _bend(sp: ShadingPoint, wi: torch.Tensor):
    """:func:`invrender.core.lanes.bend_lanes` at the points ``sp`` for directions ``wi`` (N, 3):
    (factor (N,), pdf mask (N,) bool)."""
    from invrender.backends.arrays import TORCH
    from invrender.core.lanes import bend_lanes

    nb, npert, alpha2, perturbed = sp.bend
    return bend_lanes(TORCH, (tuple(nb.unbind(1)), tuple(npert.unbind(1)), alpha2, perturbed), tuple(wi.unbind(1)))


def _empty_like(part, n: int):
    if isinstance(part, BSDFSample):
        return BSDFSample(*(_empty_like(getattr(part, f), n) for f in part.__dataclass_fields__))
    return part.new_zeros((n, *part.shape[1:]))


def _scatter(out, index: torch.Tensor, part):
    """``out`` with rows ``index`` replaced by ``part`` (out of place, so autograd sees it)."""
    if isinstance(part, BSDFSample):
        return BSDFSample(*(_scatter(getattr(out, f), index, getattr(part, f)) for f in part.__dataclass_fields__))
    return out.index_put((index,), part)


__all__ = ["BSDF", "DeltaBSDF", "HEMISPHERES", "BSDFSample", "BSDFSampling", "Lobe", "Materials", "ShadingPoint"]
