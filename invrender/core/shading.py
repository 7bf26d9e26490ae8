"""Shading frames as Mitsuba 3 builds them: the UV tangent frame, normal maps and bump maps.

The frame a material works in (z the shading normal turned to ``wo``'s geometric side) is, by
default, any orthonormal frame about the normal (:func:`invrender.core.lanes.frame`, Duff et al.):
isotropic materials do not see its tangent, and their renders keep its bits. Materials whose
value depends on the tangent's direction (an anisotropic roughness: the lane form's ``tangent``)
and materials whose normal a texture perturbs (Mitsuba's ``normalmap`` and ``bumpmap``, read as a
:class:`~invrender.scene.materials.NormalPerturbation` of the nested material) work in the frame
Mitsuba builds (``SurfaceInteraction::initialize_sh_frame``):

- per triangle, ``dp/du`` and ``dp/dv`` from its corners' positions and texture coordinates
  (:func:`tangent_rows`); a triangle without texture coordinates (all six zero) takes its edges
  ``p1 - p0`` and ``p2 - p0`` (Mitsuba's barycentric parameterization of a mesh without UVs), one
  whose UVs are degenerate (zero determinant) the coordinate system of its geometric normal;
- ``s`` = ``dp/du`` made orthogonal to the front-side shading normal ``n`` (Gram-Schmidt), ``t =
  n x s``; on the back side z is ``-n`` with s and t kept (the frame Mitsuba's ``twosided`` sees,
  in which its nested BSDF's anisotropy keeps its orientation).

A perturbation (:func:`~invrender.core.lanes.shading_frame`) gives a normal ``p`` in a base frame ``B = (s, t, sigma n)``
(``sigma`` = 1, or the side the ray arrives from where ``twosided`` wraps the map: Mitsuba's
``twosided`` flips the directions before its nested map perturbs them):

- ``normalmap``: ``p = 2 c - 1`` of the texture's filtered RGB ``c`` (tangent space), its frame
  ``s' = normalize(x - p p_x)``, ``t' = p x s'``;
- ``bumpmap``: the height texture's luminance ``f`` differentiated over uv (the bilinear filter's
  exact gradient, as Mitsuba's bitmap ``eval_1_grad``; 0 for the nearest filter) times ``scale``
  moves dp/du and dp/dv along ``n``: ``dp/du' = dp/du + n (scale df/du - n . dp/du)`` (and dp/dv),
  ``p = normalize(dp/du' x dp/dv')`` turned to the geometric normal's side, its ``s'`` dp/du made
  orthogonal to it (in B's coordinates: Mitsuba mixes world and local coordinates there, which is
  the same where B is the world's axes, and where the nested material is isotropic);
- where ``flip_invalid_normals`` (default on) and the direction towards the camera ``a`` (in B) has
  ``a_z (a . p) <= 0``, ``p`` is mirrored to ``(-p_x, -p_y, p_z)``.

The nested material then works in the perturbed frame turned to ``wo`` (its ``front``: ``wo`` on
the perturbed normal's outer side), and its value and pdf for a direction ``wi`` are kept only where
``wi`` lies on the same side of the base normal and of the perturbed one, the value times Estevez et
al.'s shadowing term (:func:`~invrender.core.lanes.bend_lanes`; "A Microfacet-Based Shadowing Function to Solve the Bump
Terminator Problem", Ray Tracing Gems 2019) ``2 / (1 + sqrt(1 + alpha^2 tan^2 theta_i))``, ``alpha^2 =
min(tan^2 theta_p / 8, 1)`` (``use_shadowing_function``, default on), as Mitsuba's wrappers do.

Everything is written once against the array interface: the compiled bounce
(:func:`invrender.core.lanes.path_vertex`) and the torch bounce
(:meth:`invrender.core.context.TransportContext.shading_point`) run the same functions on the
same tables (:func:`tables`).
"""

from __future__ import annotations

import torch

from invrender.core import lanes
from invrender.core.surface import carries_derivative

#: the perturbations' codes in the shading table (:data:`~invrender.core.lanes.SHADING_ROW`)
KINDS = {"normalmap": 1.0, "bumpmap": 2.0}


def tangent_rows(triangles) -> torch.Tensor:
    """(T * 8,) float32 each triangle's ``dp/du`` and ``dp/dv`` (3 floats each, then two zeros), as
    Mitsuba's mesh computes them (module docstring), made once per
    :class:`~invrender.scene.scene.Triangles`."""

    def build():
        e1, e2, ng = triangles.e1.double(), triangles.e2.double(), triangles.normal.double()
        uv = triangles.uv.double()
        duv0, duv1 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        det = duv0[:, 0] * duv1[:, 1] - duv0[:, 1] * duv1[:, 0]
        ok = (det != 0)[:, None]
        inv = 1.0 / torch.where(ok[:, 0], det, 1.0)[:, None]
        dpdu = (duv1[:, 1:2] * e1 - duv0[:, 1:2] * e2) * inv
        dpdv = (duv0[:, 0:1] * e2 - duv1[:, 0:1] * e1) * inv
        cs, ct, _ = lanes.frame(_TorchF64, tuple(ng.unbind(1)))  # the geometric normal's coordinate system
        dpdu = torch.where(ok, dpdu, torch.stack(cs, 1))
        dpdv = torch.where(ok, dpdv, torch.stack(ct, 1))
        bare = (uv.reshape(-1, 6) == 0).all(1)[:, None]  # no texture coordinates: barycentric
        dpdu, dpdv = torch.where(bare, e1, dpdu), torch.where(bare, e2, dpdv)
        return torch.nn.functional.pad(torch.cat([dpdu, dpdv], 1).float(), (0, 2)).reshape(-1).contiguous()

    return triangles.derived("lane_tangents", build)


class _TorchF64:
    """The one op :func:`invrender.core.lanes.frame` needs, on float64 tensors."""

    select = staticmethod(torch.where)


def tables(ctx, sampling: bool = False):
    """The shading tables of the render ``ctx`` (:class:`~invrender.core.context.TransportContext`):
    ``(frames, perturb)``, each None where nothing needs it: ``frames = (tangents (T * 8,), uvs
    (T * 8,), rows (M * 8,))`` (:func:`tangent_rows`, :func:`~invrender.core.lanes.uv_rows`, one
    :data:`~invrender.core.lanes.SHADING_ROW` per scene material) where some material needs the UV frame;
    ``perturb = (texture rows, texels)`` (a :class:`~invrender.core.lanes.TextureTable` of the
    perturbations' textures) where some material's normal is perturbed. The texels keep their
    autograd graph where a normal map's texels carry a derivative (grad on: a table of their own);
    with ``sampling``, the tables sampling reads: detached, of the normal maps sampling is held
    at (``Materials.sampling_perturbations``) where a render holds it fixed."""
    materials = ctx.materials
    perturbations = getattr(materials, "perturbations", None) or []
    held = sampling and getattr(materials, "sampling_perturbations", None) is not None
    if held:
        perturbations = materials.sampling_perturbations
    graph = not sampling and any(p is not None and carries_derivative(p.texture) for p in perturbations)  # a normal map's texels differentiated
    token = (id(ctx.triangles), str(ctx.triangles.p0.device), graph, held)
    cache = materials.__dict__.setdefault("_shading_tables", {})  # one build per render (the chunks' contexts share the materials)
    if token not in cache:
        cache[token] = _tables(ctx, perturbations or [None] * len(materials.slot_of), graph)
    return cache[token]


def _tables(ctx, perturbations: list, graph: bool):
    materials = ctx.materials
    tangent = [bool(getattr(b.lane_form(), "tangent", False)) for b in materials.bsdfs]
    slot = materials.slot_of.tolist()
    if not any(tangent) and all(p is None for p in perturbations):
        return None, None
    textures, rows = lanes.TextureTable(), []
    for m, p in enumerate(perturbations):
        row = [1.0 if tangent[slot[m]] or p is not None else 0.0] + [0.0] * (lanes.SHADING_ROW - 1)
        if p is not None:
            texture = textures.add(p.texture, p.sampling, graph=graph)
            if texture is None:
                from invrender.errors import SceneError

                raise SceneError(f"{p.source or 'a normal map'}: the perturbations' textures hold more than {lanes.TextureTable.LIMIT} texels")
            row[1:7] = [KINDS[p.kind], float(texture), float(p.scale), float(p.on_turned), float(p.flip_invalid), float(p.shadowing)]
        rows.append(row)
    device = ctx.triangles.p0.device
    frames = (tangent_rows(ctx.triangles), lanes.uv_rows(ctx.triangles), torch.tensor(rows, dtype=torch.float32, device=device).reshape(-1))
    return frames, (None if textures.empty else textures.tables(device))


def shading_point_lanes(xp, frames, perturb, ns, ng, front, prim, b1, b2, wo, mat):
    """:func:`~invrender.core.lanes.shading_frame` with its outputs flat (for :func:`invrender.core.compiled.run`): s, t, n,
    front, and with ``perturb`` the base normal, the perturbed one, alpha^2, perturbed."""
    f, front_m, bend = lanes.shading_frame(xp, frames, perturb, ns, ng, front, prim, b1, b2, wo, mat)
    return (*f, front_m) + (() if bend is None else tuple(bend))
