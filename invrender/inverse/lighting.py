"""A low-dimensional lighting basis: real spherical harmonics as the parametrization of an
``envmap`` emitter (``ir.lighting``).

**The basis.** Real, orthonormal spherical harmonics ``Y_lm`` (sphericart-torch) of the *world*
direction ``d = (x, y, z)``, ordered by ``l`` then ``m = -l..l`` (coefficient ``l^2 + l + m``):
``Y_00 = 1 / (2 sqrt pi)``, ``Y_1,-1 ~ y``, ``Y_10 ~ z``, ``Y_11 ~ x`` (sphericart's polar axis is
z; no Condon-Shortley phase). An environment of order ``l_max`` is ``L(d) = sum_lm c_lm Y_lm(d)``
with ``(l_max + 1)^2`` coefficients per RGB channel.

**As texels.** :class:`SHBasis` evaluates the basis at each texel centre of an (h, w) map in the
envmap's own convention (column j at ``u = (j + 0.5) / w``, row i at ``v' = i / (h - 1)``, the
local direction taken to the world by the emitter's ``to_world``), so ``texels = B c / scale`` is
a linear map (h w, K) of the coefficients; the envmap's bilinear lookup then interpolates it
between texel centres. :meth:`SHBasis.project` goes back: weighted least squares over the texels
(the default; exact for a map in the span) or quadrature with the texels' solid angles (the
integrals of their bilinear hats).

**Fitting.** An image is linear in the texels (sampling never depends on the differentiable
values), so it is linear in the coefficients: ``I = J_texels B c``. :func:`jacobian` computes
``J_coeff = J_texels B`` exactly for the sampling of the scene's current map by forward-mode
renders (one per coefficient, all channels at once), and :func:`fit_sh` solves the linear least
squares per channel, with standard errors and the coefficient combinations the images cannot
determine (the small singular directions of ``J_coeff``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
import torch.autograd.forward_ad as fwAD

from invrender.estimators import render
from invrender.plugins.emitters.envmap import rotation_of, texel_solid_angles, uv_to_direction
from invrender.errors import ParameterError
from invrender.inverse.targets import load_views
from invrender.scene.scene import Scene

#: the highest order accepted: (l_max + 1)^2 coefficients per channel, 289 at 16; a diffuse
#: object sees nothing above order 2, and beyond this a texel map is the better parametrization
MAX_ORDER = 16


def num_coefficients(order: int) -> int:
    """``(order + 1)^2``: the coefficients per channel of an environment of order ``order``."""
    return (int(order) + 1) ** 2


def index(l: int, m: int) -> int:  # noqa: E741
    """The coefficient index of ``Y_lm``: ``l^2 + l + m``."""
    if not (l >= 0 and -l <= m <= l):
        raise ParameterError(f"Y_lm needs l >= 0 and -l <= m <= l, got l={l}, m={m}")
    return l * l + l + m


def labels(order: int) -> list[str]:
    """``"Y[l,m]"`` for each coefficient of an environment of order ``order``, in order."""
    return [f"Y[{l},{m}]" for l in range(order + 1) for m in range(-l, l + 1)]  # noqa: E741


def degrees(order: int) -> torch.Tensor:
    """(K,) int64: the degree l of each coefficient."""
    return torch.tensor([l for l in range(order + 1) for _ in range(2 * l + 1)])  # noqa: E741


def max_order_of(h: int, w: int) -> int:
    """The highest order an h x w map resolves: two texels a period in latitude (h - 1 intervals
    over pi) and in longitude (w over 2 pi), at most :data:`MAX_ORDER`."""
    return min(MAX_ORDER, (h - 1) // 2, w // 4)


def check_order(order, h: int | None = None, w: int | None = None) -> int:
    """``order`` as an int; a one-line :class:`ParameterError` unless it lies in the range an
    (h, w) map resolves."""
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)):
        raise ParameterError(f"spherical-harmonic order must be an integer, got {order!r}")
    order = int(order)
    top = MAX_ORDER if h is None else max_order_of(h, w)
    if not 0 <= order <= top:
        why = f"the map is {h} x {w}: it resolves orders up to min({MAX_ORDER}, (h - 1) // 2, w // 4) = {top}" if h is not None else f"{num_coefficients(MAX_ORDER)} coefficients a channel at most; use texels beyond"
        raise ParameterError(f"spherical-harmonic order must be in [0, {top}] ({why}), got {order}")
    return order


def evaluate(order: int, directions: torch.Tensor) -> torch.Tensor:
    """(N, K) float64: the real orthonormal SH up to ``order`` at unit ``directions`` (N, 3)."""
    import sphericart.torch as sct  # imported on first use: it takes a second

    order = check_order(order)
    d = torch.as_tensor(directions, dtype=torch.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ParameterError(f"directions must be (N, 3), got {tuple(d.shape)}")
    if not bool(torch.isfinite(d).all()):
        raise ParameterError("directions must be finite")
    d = d / d.norm(dim=1, keepdim=True).clamp_min(1e-300)
    return sct.SphericalHarmonics(order).compute(d.contiguous())


def texel_directions(h: int, w: int, rotation=None) -> torch.Tensor:
    """(h w, 3) float64 world directions of the texel centres of an (h, w) envmap, row-major (the
    order of ``texture.reshape(-1, 3)``), under the to_world ``rotation`` (3, 3) (default none)."""
    i, j = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    uv = torch.stack([((j + 0.5) / w).reshape(-1), (i / (h - 1)).reshape(-1)], dim=1)
    local, _ = uv_to_direction(uv)
    R = torch.eye(3, dtype=torch.float64) if rotation is None else torch.as_tensor(np.asarray(rotation), dtype=torch.float64)
    return local @ R.T


@dataclasses.dataclass(frozen=True)
class SHBasis:
    """The SH basis of order ``order`` on the texels of an (h, w) envmap.

    Attributes:
        order: l_max.
        shape: (h, w).
        rotation: the envmap's to_world (3, 3) (float64 numpy).
        scale: the envmap's ``scale`` (texels are radiance / scale).
        matrix: B, (h w, K) float64: column k is ``Y_k`` at the texel centres' world directions.
        solid_angle: (h w,) float64 quadrature weights of the texels (:func:`texel_solid_angles`).
    """

    order: int
    shape: tuple[int, int]
    rotation: np.ndarray
    scale: float
    matrix: torch.Tensor
    solid_angle: torch.Tensor

    @property
    def size(self) -> int:
        """K = (order + 1)^2, the coefficients per channel."""
        return self.matrix.shape[1]

    @property
    def labels(self) -> list[str]:
        return labels(self.order)

    def check_coefficients(self, coefficients) -> torch.Tensor:
        c = coefficients if isinstance(coefficients, torch.Tensor) else torch.as_tensor(np.asarray(coefficients, dtype=np.float64))
        if c.shape != (self.size, 3):
            raise ParameterError(f"SH coefficients of order {self.order} must be ({self.size}, 3) (K = (l_max + 1)^2 rows, RGB), got {tuple(c.shape)}")
        if not bool(torch.isfinite(c.detach()).all()):
            raise ParameterError("SH coefficients must be finite")
        return c

    def texels(self, coefficients, dtype=torch.float32) -> torch.Tensor:
        """(h, w, 3) texels ``B c / scale`` of coefficients (K, 3): differentiable (autograd and
        forward mode), linear. May be negative where the environment is: the renderer takes
        non-negative maps only (add a constant, whose render is known, to render one)."""
        c = self.check_coefficients(coefficients)
        t = (self.matrix.to(c.device) @ c.to(torch.float64)) / self.scale
        return t.reshape(*self.shape, 3).to(dtype)

    def project(self, texture, method: str = "lstsq") -> torch.Tensor:
        """(K, 3) float64 coefficients of an (h, w, 3) map: ``"lstsq"`` (least squares weighted by
        the texels' solid angles: :meth:`texels` of the result is the closest map of the span, and
        the map of coefficients gives them back exactly) or ``"quadrature"`` (``c_lm = sum_texels
        solid_angle Y_lm L``, the projection integral by the bilinear hats)."""
        t = texture if isinstance(texture, torch.Tensor) else torch.as_tensor(np.asarray(texture, dtype=np.float64))
        if t.shape != (*self.shape, 3):
            raise ParameterError(f"the map must be {self.shape[0]} x {self.shape[1]} x 3 to project on this basis, got {tuple(t.shape)}")
        t = t.detach().to(torch.float64).reshape(-1, 3) * self.scale
        if not bool(torch.isfinite(t).all()):
            raise ParameterError("the map must be finite to project it")
        if method == "quadrature":
            return self.matrix.T @ (self.solid_angle[:, None] * t)
        if method != "lstsq":
            raise ParameterError(f"unknown projection method {method!r} (known: lstsq, quadrature)")
        s = self.solid_angle.sqrt()[:, None]
        return torch.linalg.lstsq(s * self.matrix, s * t).solution


def sh_basis(order, shape, rotation=None, scale: float = 1.0) -> SHBasis:
    """The :class:`SHBasis` of ``order`` on an (h, w) map (h >= 3 rows, w >= 2 columns: the
    smallest map the envmap does not pad) rotated by ``rotation`` (to_world, 3 x 3)."""
    if not (isinstance(shape, (tuple, list)) and len(shape) == 2 and all(isinstance(s, (int, np.integer)) for s in shape)):
        raise ParameterError(f"map shape must be (h, w), got {shape!r}")
    h, w = int(shape[0]), int(shape[1])
    if h < 3 or w < 2:
        raise ParameterError(f"an SH map needs at least 3 rows x 2 columns (smaller maps are padded by the envmap), got {h} x {w}")
    order = check_order(order, h, w)
    if not (math.isfinite(scale) and scale > 0):
        raise ParameterError(f"scale must be finite and > 0, got {scale}")
    R = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ParameterError(f"rotation must be a finite 3 x 3 matrix, got shape {R.shape}")
    B = evaluate(order, texel_directions(h, w, R))
    return SHBasis(order, (h, w), R, float(scale), B, texel_solid_angles(h, w))


def emitter_basis(scene: Scene, emitter: str = "sky", order=2, shape=None) -> SHBasis:
    """The :class:`SHBasis` of the envmap ``emitter`` of ``scene``: its rotation and scale, and
    the shape of its current map (or ``shape``)."""
    k = _envmap_index(scene, emitter)
    spec = scene.emitter_spec(k)
    current = scene.params[f"{emitter}.emission"]
    if shape is None:
        if current.ndim != 3:
            raise ParameterError(f"{emitter}.emission is one RGB value, not a map: give the map's shape=(h, w)")
        shape = (int(current.shape[0]), int(current.shape[1]))
    return sh_basis(order, shape, rotation_of(dict(spec.constants)), float(spec.constants.get("scale", 1.0)))


def _envmap_index(scene: Scene, emitter: str) -> int:
    if emitter not in scene.emitters:
        raise ParameterError(f"no emitter {emitter!r} in the scene (emitters: {', '.join(scene.emitters) or 'none'})")
    k = scene.emitters.index(emitter)
    kind = scene.emitter_spec(k).type
    if kind != "envmap":
        raise ParameterError(f"emitter {emitter!r} is of type {kind!r}: spherical harmonics parametrize an envmap")
    return k


def with_coefficients(scene: Scene, coefficients, emitter: str = "sky", basis: SHBasis | None = None, offset: float = 0.0) -> Scene:
    """``scene`` with the envmap ``emitter``'s map set to the SH environment of ``coefficients``
    (K, 3) plus ``offset`` (radiance added everywhere, so a map with negative lobes can render:
    a convex diffuse object's radiance under the offset alone is rho x offset)."""
    c = torch.as_tensor(coefficients) if not isinstance(coefficients, torch.Tensor) else coefficients
    basis = basis or emitter_basis(scene, emitter, order=math.isqrt(c.shape[0]) - 1 if c.ndim == 2 else 0)
    return scene.with_params({f"{emitter}.emission": basis.texels(c) + offset / basis.scale})


def jacobian(scene: Scene, basis: SHBasis, emitter: str = "sky", *, integrator="path", spp: int = 64, max_depth: int | None = 2, seed: int = 0, sampler: str = "stratified", progress: bool = False) -> torch.Tensor:
    """(H, W, 3, K) float64: ``dI / dc_k`` of the image of ``scene``, channel by channel (a
    channel of the image depends on the same channel of the coefficients only), for the paths the
    scene's current map samples (its values fix the sampling, its derivative is ``B``): exact for
    those paths, because the image is linear in the texels. One forward-mode render per
    coefficient."""
    _envmap_index(scene, emitter)
    name = f"{emitter}.emission"
    current = scene.params[name].detach()
    if current.shape != (*basis.shape, 3):
        raise ParameterError(f"{name} is {tuple(current.shape)} but the basis is for a {basis.shape[0]} x {basis.shape[1]} x 3 map")
    columns = []
    for k in range(basis.size):
        tangent = (basis.matrix[:, k] / basis.scale).to(current.dtype).reshape(*basis.shape, 1).expand(*basis.shape, 3).contiguous()
        with torch.no_grad(), fwAD.dual_level():
            params = {n: v.detach() for n, v in scene.params.items()}
            params[name] = fwAD.make_dual(current, tangent)
            dual = render(dataclasses.replace(scene, params=params), integrator, spp=spp, max_depth=max_depth, seed=seed, sampler=sampler, progress=progress)
            _, t = fwAD.unpack_dual(dual)
            columns.append(torch.zeros(dual.shape, dtype=torch.float64) if t is None else t.detach().double().clone())
    return torch.stack(columns, dim=-1)


@dataclasses.dataclass
class SHFit:
    """What :func:`fit_sh` recovered.

    Attributes:
        coefficients: (K, 3) float64 least-squares coefficients (the minimum-norm solution: the
            undetermined combinations are zero).
        std_error: (K, 3) standard errors (the determined part; from the residual's scatter and
            the Jacobian's Monte Carlo noise).
        singular_values: (3, K) per channel, largest first, of ``J_coeff``.
        noise: (3, K) the Monte Carlo noise of ``J_coeff`` along each singular direction.
        determined: (3, K) bool per singular direction.
        directions: (3, K, K) the right singular vectors per channel (rows).
        undetermined: the coefficient labels the images cannot determine: those more than half
            of whose unit vector lies in the undetermined subspace of some channel.
        basis: the :class:`SHBasis`.
    """

    coefficients: torch.Tensor
    std_error: torch.Tensor
    singular_values: torch.Tensor
    noise: torch.Tensor
    determined: torch.Tensor
    directions: torch.Tensor
    undetermined: list[str]
    basis: SHBasis

    def texels(self) -> torch.Tensor:
        """The recovered map (h, w, 3) (may be negative where the fit is)."""
        return self.basis.texels(self.coefficients)

    def describe(self) -> str:
        """The undetermined coefficients, one line (empty when every one is determined)."""
        return ", ".join(self.undetermined)

    def undetermined_orders(self) -> list[int]:
        """The orders all of whose coefficients are undetermined."""
        un = set(self.undetermined)
        return [l for l in range(self.basis.order + 1) if all(f"Y[{l},{m}]" in un for m in range(-l, l + 1))]  # noqa: E741


def fit_sh(
    scene: Scene,
    targets,
    emitter: str = "sky",
    order=2,
    *,
    cameras=None,
    integrator="path",
    spp: int = 64,
    max_depth: int | None = 2,
    seed: int = 0,
    rtol: float = 1e-2,
    snr: float = 3.0,
    sampler: str = "stratified",
    progress: bool = False,
) -> SHFit:
    """SH coefficients of the envmap ``emitter`` that reproduce ``targets`` (one image, or one per
    camera), by linear least squares on ``J_coeff = J_texels B`` (:func:`jacobian`, from two
    independent sets of paths whose mean is used and whose difference measures its noise), at the
    sampling of the scene's current map (of the basis's shape).

    A singular direction of ``J_coeff`` (per channel) is undetermined when its singular value is
    below ``rtol`` times the largest, or below ``snr`` times the Monte Carlo noise of ``J_coeff``
    along it (then what the images show of it is indistinguishable from noise at ``spp``).
    """
    basis = emitter_basis(scene, emitter, order)
    views = load_views(scene, targets, cameras)
    sets = []
    for half in (0, 1):
        rows = [jacobian(v, basis, emitter, integrator=integrator, spp=spp, max_depth=max_depth, seed=2 * (seed * len(views) + i) + half, sampler=sampler, progress=progress) for i, (v, _) in enumerate(views)]
        sets.append(torch.cat([r.reshape(-1, 3, basis.size) for r in rows]))
    J = 0.5 * (sets[0] + sets[1])
    dJ = 0.5 * (sets[0] - sets[1])  # the noise of the mean
    T = torch.cat([t.double().reshape(-1, 3) for _, t in views])
    K = basis.size
    coeffs, se = torch.zeros(K, 3, dtype=torch.float64), torch.zeros(K, 3, dtype=torch.float64)
    sv, nv, det, dirs = torch.zeros(3, K, dtype=torch.float64), torch.zeros(3, K, dtype=torch.float64), torch.zeros(3, K, dtype=torch.bool), torch.zeros(3, K, K, dtype=torch.float64)
    weak = set()
    for ch in range(3):
        A, N = J[:, ch, :], dJ[:, ch, :]
        U, S, Vh = torch.linalg.svd(A, full_matrices=False)
        noise = (N @ Vh.T).norm(dim=0)
        ok = (S > rtol * S[0]) & (S > snr * noise) if float(S[0]) > 0 else torch.zeros(K, dtype=torch.bool)
        sv[ch], nv[ch], det[ch], dirs[ch] = S, noise, ok, Vh
        Vk, Sk, Uk = Vh[ok], S[ok], U[:, ok]
        x = Vk.T @ ((Uk.T @ T[:, ch]) / Sk)
        coeffs[:, ch] = x
        r = T[:, ch] - A @ x
        dof = max(A.shape[0] - int(ok.sum()), 1)
        s2 = float((r * r).sum()) / dof
        # the residual's scatter and the Jacobian's noise times the solution, through the pseudo-inverse
        s2 = s2 + float(((N @ x) ** 2).sum()) / A.shape[0]
        se[:, ch] = ((Vk.T / Sk) ** 2).sum(1).sqrt() * math.sqrt(s2)
        P = Vh[~ok].T @ Vh[~ok]  # the projector on the undetermined subspace
        weak.update(int(i) for i in torch.nonzero(P.diagonal() > 0.5).reshape(-1).tolist())
    names = basis.labels
    return SHFit(coeffs, se, sv, nv, det, dirs, [names[i] for i in sorted(weak)], basis)


# the texel route: the transport matrix of the map and its regularized non-negative solve
from invrender.estimators.transport_matrix import TransportMatrix, transport_matrix  # noqa: E402, F401
from invrender.estimators.map_basis import MapBasis  # noqa: E402, F401
from invrender.inverse.map_fit import MapFit, fit_map, solve_map, sphere_smoothness  # noqa: E402, F401
from invrender.inverse.map_normal import NormalEquations, normal_equations  # noqa: E402, F401
# relighting: a recovered map put into another scene, compared and shown
from invrender.inverse.relighting import relight, relighting_error, relighting_figure  # noqa: E402, F401
# joint lighting and materials: the map and reflectances by alternating exact solves
from invrender.inverse.joint_fit import JointFit, fit_joint, scale_anchor  # noqa: E402, F401
