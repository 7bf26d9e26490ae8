"""Parameter kinds: what each differentiable scene parameter is, in one registry.

A parameter's name is ``"<owner>.<kind>"`` (``"red.reflectance"``, ``"light.emission"``,
``"mirror.specular_reflectance"``, ``"ambient.emission"``). Its kind fixes everything the rest of
the program needs to know about it: the range its values must lie in (checked when a scene is built
or a value is set), whether it may be a texture, the reparametrization ``fit`` moves it by, the
default Adam step of that move, and the finite-difference step ``gradcheck`` uses. Nothing else
reads a parameter's name to decide how to treat it: callers ask :func:`kind_of`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch

from invrender.errors import ParameterError

#: smallest reflectance-like value a fit's sigmoid reaches (keeps logit finite)
UNIT_MIN = 1e-4
#: smallest emission a fit's exp starts from (keeps log finite)
POSITIVE_MIN = 1e-6


@dataclass(frozen=True)
class ParamKind:
    """One kind of differentiable parameter.

    Attributes:
        key: the name's suffix and the scene formats' key (``"reflectance"``).
        symbol: its symbol in the rendering equation (``"rho"``, ``"eps"``, ``"k_s"``).
        upper: values lie in ``[0, upper]``; ``math.inf`` = unbounded above.
        texture: may vary over the surface as an (h, w, 3) texture (else an RGB triple only).
        reparam: how ``fit`` keeps values in range: ``"sigmoid"`` (value = sigmoid(x), in (0, 1)),
            ``"exp"`` (value = exp(x), > 0) or ``"unit"`` (a normal = x / |x|: :attr:`unit`).
        lr_setting: the :class:`~invrender.inverse.fit.FitSettings` field holding its Adam step
            (``"lr"`` for [0, 1] kinds, in logit units; ``"lr_emission"``, in log units;
            ``"lr_normals"`` for normals, about radians).
        fd_step: ``gradcheck``'s central-difference step, relative to the value (absolute below 1).
        doc: one line for messages and docs.
        positive: values must be > 0 (the range is ``(0, upper]``), not merely >= 0.
        polynomial: a path's weight is a polynomial in it (each BSDF or emitter factor linear in
            it), so path records (:mod:`invrender.estimators.records`) can represent it; False for
            parameters that enter non-linearly (roughness).
        grey: one number stored as three equal channels (the RGB form every parameter shares);
            the BSDF reads their mean.
        differentiable: False for a value the renderer reads detached (a mask's opacity decides
            visibility, which is never differentiated): it may be set, not fitted or differentiated.
        unit: a direction, not an amount (the shading normals, :data:`NORMALS` and
            :data:`NORMALMAP`): ``"vector"``, the value is unit 3-vectors (any sign); ``"texel"``,
            the value is a normal map's texels ``c`` in [0, 1], the tangent-space normal
            ``2 c - 1``. Either way a normal must be finite and of length >= :data:`MIN_NORMAL`
            (a grey texel has none); vertex normals set are normalized (a normal map's texels are
            kept as given: the renderer normalizes after filtering, as Mitsuba does). ``fit`` moves the unnormalized
            vector (``reparam`` ``"unit"``) and normalizes it after each Adam step; only Adam fits
            them (:attr:`adam_only`).
    """

    key: str
    symbol: str
    upper: float
    texture: bool
    reparam: str
    lr_setting: str
    fd_step: float
    doc: str
    positive: bool = False
    polynomial: bool = True
    grey: bool = False
    differentiable: bool = True
    unit: str | None = None

    @property
    def adam_only(self) -> bool:
        """Only Adam fits it: a normal turns the frame every BSDF is evaluated in, which neither
        path records (not a polynomial factor) nor forward-mode re-traced renders follow."""
        return self.unit is not None

    def check(self, name: str, value: torch.Tensor) -> None:
        """A :class:`ParameterError` naming ``name`` when ``value`` lies outside this kind's range."""
        if self.unit is not None:
            return self._check_unit(name, value)
        if value.ndim == 3 and not self.texture:
            raise ParameterError(f"{name}: {self.key} must be an RGB triple, not a texture")
        if self.grey and value.shape[-1] == 3 and not bool((value == value[..., :1]).all()):
            raise ParameterError(f"{name}: {self.key} {self.symbol} is one number (three equal channels), got {_short(value)}")
        lo, hi = float(value.min()), float(value.max())
        if (lo <= 0 if self.positive else lo < 0) or hi > self.upper:
            low = "(0" if self.positive else "[0"
            expected = f"lie in {low}, {self.upper:g}]" if math.isfinite(self.upper) else ("be > 0" if self.positive else "be >= 0")
            raise ParameterError(f"{name}: {self.key} {self.symbol} must {expected}, got values in [{lo:.4g}, {hi:.4g}]")

    def _check_unit(self, name: str, value: torch.Tensor) -> None:
        """The checks of a normal's kind (:attr:`unit`): the shape, the texels' range, every
        normal of length >= :data:`MIN_NORMAL` (finiteness is checked before)."""
        if self.unit == "texel":
            if value.ndim != 3:
                raise ParameterError(f"{name}: a normal map is an (h, w, 3) texture of texels c, the normals 2 c - 1, got shape {tuple(value.shape)}")
            lo, hi = float(value.min()), float(value.max())
            if lo < 0 or hi > 1:
                raise ParameterError(f"{name}: a normal map's texels c must lie in [0, 1] (the normal is 2 c - 1), got values in [{lo:.4g}, {hi:.4g}]")
        length = self.normals(value).norm(dim=-1)
        short = length < MIN_NORMAL
        if bool(short.any()):
            where = [int(i) for i in short.nonzero()[0]]
            at = f"texel (row {where[0]}, column {where[1]})" if value.ndim == 3 else f"row {where[0]}"
            raise ParameterError(f"{name}: the normal at {at} has length {float(length[tuple(where)]):.3g} (below {MIN_NORMAL:g}: no direction); a normal must be a non-zero vector")

    def normals(self, value: torch.Tensor) -> torch.Tensor:
        """The (unnormalized) normals a value of a :attr:`unit` kind holds: the vectors themselves,
        or a normal map's ``2 c - 1``."""
        return 2.0 * value - 1.0 if self.unit == "texel" else value

    def normalized(self, value: torch.Tensor) -> torch.Tensor:
        """A value as a scene keeps it: vertex normals (``unit == "vector"``) made unit length
        (differentiable); any other value (a normal map's texels too) as it is."""
        if self.unit != "vector":
            return value
        return value / value.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    def renormalize_(self, raw: torch.Tensor) -> None:
        """Bring ``fit``'s unconstrained vectors of a :attr:`unit` kind back to unit length in place
        (after an Adam step), so that a step of a given size turns them by the same angle."""
        if self.unit is not None:
            with torch.no_grad():
                raw.div_(raw.norm(dim=-1, keepdim=True).clamp_min(1e-12))

    def to_raw(self, value: torch.Tensor) -> torch.Tensor:
        """The unconstrained tensor ``fit`` moves, from a value (detached copy)."""
        v = value.detach().clone()
        if self.reparam == "unit":
            n = self.normals(v)
            return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        if self.reparam == "exp":
            return v.clamp_min(POSITIVE_MIN).log()
        return torch.logit(v.clamp(UNIT_MIN, 1.0 - UNIT_MIN))

    def from_raw(self, raw: torch.Tensor) -> torch.Tensor:
        """The value (differentiable) from the unconstrained tensor."""
        if self.reparam == "unit":
            n = raw / raw.norm(dim=-1, keepdim=True).clamp_min(1e-12)
            return 0.5 * (n + 1.0) if self.unit == "texel" else n
        return raw.exp() if self.reparam == "exp" else torch.sigmoid(raw)

    def fd_interval(self, value: float) -> float:
        """Central-difference step at ``value``, kept inside the range on both sides (a normal's
        component: the step itself; the renderer normalizes a normal, so no range binds it)."""
        if self.unit is not None:
            return self.fd_step
        step = self.fd_step * max(1.0, abs(value))
        if math.isfinite(self.upper):
            step = min(step, max(value, 1e-6), max(self.upper - value, 1e-6))
        if self.positive:
            step = min(step, 0.5 * value)  # value - step stays > 0
        return step


REFLECTANCE = ParamKind("reflectance", "rho", 1.0, True, "sigmoid", "lr", 1e-2, "diffuse albedo rho, in [0, 1]")
SPECULAR_REFLECTANCE = ParamKind(
    "specular_reflectance", "k_s", 1.0, True, "sigmoid", "lr", 1e-2, "specular reflectance k_s of a mirror or glossy conductor, in [0, 1]"
)
#: specular reflectance that cannot vary over a surface (a mirror's): the same kind, RGB only
SPECULAR_REFLECTANCE_RGB = dataclasses.replace(SPECULAR_REFLECTANCE, texture=False)
EMISSION = ParamKind("emission", "eps", math.inf, True, "exp", "lr_emission", 1e-2, "emitted radiance eps, >= 0")

#: emission that cannot vary over a surface (lights without one: skies, point, spot and directional
#: lights): the same kind, an RGB triple only
EMISSION_RGB = dataclasses.replace(EMISSION, texture=False)

# ---- microfacet roughness (glossy materials): not a polynomial factor of a path's weight

#: the roughness alpha of a microfacet distribution (GGX, Beckmann), in (0, 1]: one number (kept
#: as three equal channels), or a map over the mesh UVs ((h, w), kept as (h, w, 3) grey texels,
#: filtered bilinearly as reflectance textures are); fitted as sigmoid(x) in logit units (``lr``);
#: path records cannot represent it (fit it with Adam)
ROUGHNESS = ParamKind(
    "roughness", "alpha", 1.0, True, "sigmoid", "lr", 1e-2, "microfacet roughness alpha of a glossy material, in (0, 1]",
    positive=True, polynomial=False, grey=True,
)  # fmt: skip

# ---- the principled materials' (Mitsuba's principled, principledthin: Burley's Disney BSDF)

#: the base colour of a principled material: the diffuse albedo, the metal's and the tint's colour
#: (it enters through a luminance normalization and a square root, so not a polynomial factor)
BASE_COLOR = ParamKind("base_color", "c_base", 1.0, True, "sigmoid", "lr", 1e-2, "base colour of a principled material, in [0, 1]", polynomial=False)


def _weight(key: str, symbol: str, doc: str) -> ParamKind:
    """A principled material's blend weight: one number in [0, 1] (three equal channels) or a grey
    map, fitted as sigmoid(x), entering non-linearly."""
    return ParamKind(key, symbol, 1.0, True, "sigmoid", "lr", 1e-2, doc, polynomial=False, grey=True)


METALLIC = _weight("metallic", "metallic", "metallic weight of a principled material, in [0, 1]")
SPEC_TINT = _weight("spec_tint", "spec_tint", "how far a principled material's dielectric specular is tinted towards its base colour, in [0, 1]")
ANISOTROPIC = _weight("anisotropic", "anisotropic", "anisotropy of a principled material's specular lobes, in [0, 1]")
SHEEN = _weight("sheen", "sheen", "sheen weight of a principled material, in [0, 1]")
SHEEN_TINT = _weight("sheen_tint", "sheen_tint", "how far a principled material's sheen is tinted towards its base colour, in [0, 1]")
CLEARCOAT = _weight("clearcoat", "clearcoat", "clearcoat weight of a principled material, in [0, 1]")
CLEARCOAT_GLOSS = _weight("clearcoat_gloss", "clearcoat_gloss", "glossiness of a principled material's clearcoat, in [0, 1]")
SPEC_TRANS = _weight("spec_trans", "spec_trans", "specular transmission weight of a principled material, in [0, 1]")
FLATNESS = _weight("flatness", "flatness", "blend of a principled material's diffuse towards its fake subsurface lobe, in [0, 1]")
#: the principled materials' kinds, by key
PRINCIPLED_KINDS = (BASE_COLOR, METALLIC, SPEC_TINT, ANISOTROPIC, SHEEN, SHEEN_TINT, CLEARCOAT, CLEARCOAT_GLOSS, SPEC_TRANS, FLATNESS)

# ---- materials made of nested materials (invrender.plugins.bsdfs.blend, .mask)

#: the weight of a blend's second material (Mitsuba's blendbsdf ``weight``): the material is
#: ``(1 - w) f_0 + w f_1``, a sum, so not one monomial
BLEND_WEIGHT = _weight("weight", "w", "weight of a blendbsdf's second material, in [0, 1]")
#: a mask's opacity (Mitsuba's ``mask``): light passes straight through with probability 1 - opacity.
#: It decides what is seen, and geometry is never differentiated here: the material reads it
#: detached, so its derivative is zero (not a parameter to fit)
OPACITY = dataclasses.replace(_weight("opacity", "opacity", "opacity of a mask (read detached: visibility is fixed), in [0, 1]"), differentiable=False)

# ---- shading normals: directions, fitted by Adam alone

#: shortest normal a value may hold (the Mitsuba reader's bound for a normal map's texels: a grey
#: texel, 2 c - 1 = 0, has no direction)
MIN_NORMAL = 0.01
#: the vertex normals of the meshes of a material (``"<material>.normals"``): (V, 3) unit vectors,
#: one row per vertex of those meshes (meshes in scene order), interpolated over each triangle
#: into its shading normal; only materials whose every mesh carries vertex normals have them
NORMALS = ParamKind(
    "normals", "n", 1.0, False, "unit", "lr_normals", 1e-2, "vertex normals n of a material's meshes, unit 3-vectors (V, 3)",
    polynomial=False, unit="vector",
)  # fmt: skip
#: a normal map's texels (``"<material>.normalmap"``, the material a ``normalmap`` wraps): (h, w, 3)
#: texels c in [0, 1], the tangent-space normal 2 c - 1 (Mitsuba's encoding)
NORMALMAP = ParamKind(
    "normalmap", "c_n", 1.0, True, "unit", "lr_normals", 1e-2, "normal map texels c of a material, tangent-space normal 2 c - 1, (h, w, 3) in [0, 1]",
    polynomial=False, unit="texel",
)  # fmt: skip

#: every kind of a scene parameter, by key
KINDS: dict[str, ParamKind] = {k.key: k for k in (REFLECTANCE, SPECULAR_REFLECTANCE, EMISSION, ROUGHNESS, *PRINCIPLED_KINDS, BLEND_WEIGHT, OPACITY, NORMALS, NORMALMAP)}


def _short(value: torch.Tensor) -> str:
    return str([round(float(x), 4) for x in value.reshape(-1)[:6]]) + (" ..." if value.numel() > 6 else "")


#: the owner of the camera's sensor parameters (``"sensor.exposure"``), which every fit has beside
#: the scene's (invrender.inverse.sensor): ``value = response(exposure_v * white_balance_v * radiance)``
SENSOR = "sensor"
#: exposure of a view: a positive scalar, 1 = the scene's radiance as it is (log-space Adam steps)
EXPOSURE = ParamKind("exposure", "e", math.inf, False, "exp", "lr_sensor", 1e-2, "exposure e of a view, a positive scalar multiplying its radiance")
#: white balance of a view: RGB gains, green fixed at 1 (the common scale is the exposure's)
WHITE_BALANCE = ParamKind("white_balance", "wb", math.inf, False, "exp", "lr_sensor", 1e-2, "white balance wb of a view, RGB gains with green = 1")
SENSOR_KINDS: dict[str, ParamKind] = {k.key: k for k in (EXPOSURE, WHITE_BALANCE)}


def kind_of(name: str) -> ParamKind:
    """The kind of the parameter ``name`` (``"<owner>.<kind>"``; ``"sensor.exposure"`` and
    ``"sensor.white_balance"`` are the sensor's)."""
    owner, _, key = name.rpartition(".")
    if owner == SENSOR and key in SENSOR_KINDS:
        return SENSOR_KINDS[key]
    if not owner or key not in KINDS:
        raise ParameterError(f"{name!r} is not a parameter name '<owner>.<kind>' with kind one of {', '.join(KINDS)}")
    return KINDS[key]


def param_name(owner: str, kind: ParamKind | str) -> str:
    """``"<owner>.<kind>"``."""
    return f"{owner}.{kind if isinstance(kind, str) else kind.key}"
