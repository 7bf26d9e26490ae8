"""The camera's sensor in the model: per-view exposure and white balance.

A fit compares view v's target with ``response(g_v * I_v)``, ``I_v`` the rendered linear radiance
(H, W, 3) and ``g_v = exposure_v * white_balance_v`` (3,) the view's gains (the response is applied
on the target's side: :mod:`invrender.inverse.targets`). ``sensor.exposure`` is a positive scalar
per view, ``sensor.white_balance`` RGB gains per view with green fixed at 1: exposure and white
balance share one scale (doubling every gain is doubling the exposure), and fixing the green gain
gives that scale to the exposure alone. Either is shared by all views when the fit's ``sensor``
options say so (one camera setting for a whole set of photographs). A sensor parameter is fitted
when named in ``params`` and held at its value (1 unless given) otherwise.

Both are log-space variables (kinds ``exposure`` and ``white_balance`` in
:mod:`invrender.scene.kinds`, reparametrization exp), so the log gains are *linear* in the free
variables ``s`` (K,): ``log g = A s + b`` with a constant (V * 3, K) matrix ``A`` (:attr:`Sensor.A`).
The model image ``g_v * I_v`` stays a polynomial times exponentials of ``s``; its derivative with
respect to ``s_k`` is ``g_v * I_v * A[v, :, k]``, what the least-squares solver appends as columns
of the Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.errors import ParameterError, did_you_mean
from invrender.scene.kinds import SENSOR, kind_of

EXPOSURE = f"{SENSOR}.exposure"
WHITE_BALANCE = f"{SENSOR}.white_balance"
NAMES = (EXPOSURE, WHITE_BALANCE)
#: the keys of a fit's ``sensor`` options
OPTION_KEYS = ("exposure", "white_balance", "shared")


def is_sensor(name: str) -> bool:
    return name in NAMES


@dataclass(frozen=True)
class Sensor:
    """The sensor of a fit with ``views`` views.

    Attributes:
        views: number of views V.
        free: the sensor parameters fitted (a subset of :data:`NAMES`).
        shared: those of :data:`NAMES` one value serves every view for.
        exposure: (V,) float64 starting (or fixed) exposures.
        white_balance: (V, 3) float64 starting (or fixed) gains, green = 1.
    """

    views: int
    free: tuple[str, ...]
    shared: tuple[str, ...]
    exposure: torch.Tensor
    white_balance: torch.Tensor

    @staticmethod
    def make(views: int, names, options: dict | None = None) -> "Sensor":
        """The sensor of ``views`` views with the sensor names among ``names`` free, from the fit's
        ``sensor`` options: ``exposure`` (a number, or one per view), ``white_balance`` (RGB, or one
        RGB per view; green must be 1) and ``shared`` (a list of ``"exposure"``,
        ``"white_balance"``). Every key is checked; a ParameterError names the bad one."""
        if options is not None and not isinstance(options, dict):
            raise ParameterError(f"sensor options must be a mapping of {', '.join(OPTION_KEYS)}, got {options!r:.60}")
        options = dict(options or {})
        unknown = set(options) - set(OPTION_KEYS)
        if unknown:
            raise ParameterError(f"unknown sensor option {sorted(unknown)[0]!r}{did_you_mean(sorted(unknown)[0], OPTION_KEYS)} (known: {', '.join(OPTION_KEYS)})")
        shared = options.get("shared", ())
        shared = [shared] if isinstance(shared, str) else shared
        if not isinstance(shared, (list, tuple)):
            raise ParameterError(f"sensor option shared must be a list of 'exposure', 'white_balance', got {shared!r:.60}")
        for s in shared:
            if s not in ("exposure", "white_balance"):
                raise ParameterError(f"sensor option shared: {s!r} is not 'exposure' or 'white_balance'")
        exposure = _per_view(options.get("exposure", 1.0), views, (), "exposure")
        wb = _per_view(options.get("white_balance", [1.0, 1.0, 1.0]), views, (3,), "white_balance")
        if bool((exposure <= 0).any()) or bool((wb <= 0).any()):
            raise ParameterError("sensor options exposure and white_balance must be positive")
        if not bool(torch.allclose(wb[:, 1], torch.ones(views, dtype=torch.float64))):
            raise ParameterError("sensor option white_balance: the green gain is fixed at 1 (the common scale is the exposure's)")
        for key, value in (("exposure", exposure), ("white_balance", wb)):
            if key in shared and not bool((value == value[:1]).all()):
                raise ParameterError(f"sensor option {key} is shared but differs between views")
        free = tuple(n for n in NAMES if n in list(names))
        return Sensor(views, free, tuple(f"{SENSOR}.{s}" for s in shared), exposure, wb)

    @property
    def active(self) -> bool:
        """Whether the sensor changes anything: a free parameter, or a fixed value other than 1."""
        return bool(self.free) or not bool((self.exposure == 1).all() and (self.white_balance == 1).all())

    def _count(self, name: str) -> int:
        return 1 if name in self.shared else self.views

    def _slots(self):
        """(name, view-group index, channel or None, A's column) of each free variable."""
        k = 0
        for name in self.free:
            for i in range(self._count(name)):
                for c in (None,) if name == EXPOSURE else (0, 2):
                    yield name, i, c, k
                    k += 1

    @property
    def size(self) -> int:
        """K, the number of free variables."""
        return sum(1 for _ in self._slots())

    @property
    def A(self) -> torch.Tensor:
        """(V, 3, K) float64: d log g[v, c] / d s[k]."""
        A = torch.zeros(self.views, 3, self.size, dtype=torch.float64)
        for name, i, c, k in self._slots():
            views = range(self.views) if name in self.shared else [i]
            for v in views:
                if c is None:
                    A[v, :, k] = 1.0
                else:
                    A[v, c, k] = 1.0
        return A

    def to_raw(self, values: dict | None = None) -> torch.Tensor:
        """(K,) float64 log values of the free variables at ``values`` (name -> (V,) exposures or
        (V, 3) gains; default the starting ones)."""
        values = values or {}
        e = torch.as_tensor(values.get(EXPOSURE, self.exposure), dtype=torch.float64).reshape(self.views)
        wb = torch.as_tensor(values.get(WHITE_BALANCE, self.white_balance), dtype=torch.float64).reshape(self.views, 3)
        out = [float(e[i]) if c is None else float(wb[i, c]) for name, i, c, _ in self._slots()]
        return torch.tensor(out, dtype=torch.float64).clamp_min(1e-12).log()

    def values(self, s: torch.Tensor) -> dict:
        """name -> value of every sensor parameter at free log values ``s`` (K,): ``exposure``
        (V,), ``white_balance`` (V, 3); differentiable in ``s``."""
        e = [self.exposure[v].to(s) for v in range(self.views)]
        wb = [[self.white_balance[v, c].to(s) for c in range(3)] for v in range(self.views)]
        for name, i, c, k in self._slots():
            value = s[k].exp()
            for v in range(self.views) if name in self.shared else [i]:
                if c is None:
                    e[v] = value
                else:
                    wb[v][c] = value
        return {EXPOSURE: torch.stack(e), WHITE_BALANCE: torch.stack([torch.stack(w) for w in wb])}

    def gains(self, s: torch.Tensor) -> torch.Tensor:
        """(V, 3) ``exposure_v * white_balance_v`` at free log values ``s``; differentiable."""
        v = self.values(s)
        return v[EXPOSURE][:, None] * v[WHITE_BALANCE]

    def labels(self) -> list[str]:
        """One label per free variable: ``"sensor.exposure[v0]"`` (``"sensor.exposure"`` when shared
        or with one view), ``"sensor.white_balance[v0][R]"``."""
        out = []
        for name, i, c, _ in self._slots():
            view = "" if (name in self.shared or self.views == 1) else f"[v{i}]"
            out.append(f"{name}{view}" + ("" if c is None else f"[{'RGB'[c]}]"))
        return out

    def std_error(self, values: dict, se_log: torch.Tensor) -> dict:
        """name -> standard errors of the free sensor parameters (exposure (V,), white balance
        (V, 3), green 0) from the log variables' (K,) ``se_log`` at ``values``."""
        out = {n: torch.zeros_like(values[n], dtype=torch.float64) for n in self.free}
        for name, i, c, k in self._slots():
            for v in range(self.views) if name in self.shared else [i]:
                if c is None:
                    out[name][v] = values[name][v] * se_log[k]
                else:
                    out[name][v, c] = values[name][v, c] * se_log[k]
        return out

    def ambiguities(self, names, scene_params: dict) -> list[str]:
        """The scale ambiguities between the sensor and the emissions that no image can resolve,
        one line each, with the fixed value that resolves it, when both sides are free:

        - every exposure free (none fixed) and every emission of the scene free: scaling every
          emission by t and every exposure by 1/t leaves every image as it is;
        - the white balance free and every emission free: the same per colour channel (red and
          blue against green), i.e. the white balance against the emissions' colour."""
        names = list(names)
        emissions = [n for n, v in scene_params.items() if kind_of(n).key == "emission" and bool((v.detach() != 0).any())]
        if not emissions or not all(n in names for n in emissions):
            return []
        listed = ", ".join(emissions)
        out = []
        if EXPOSURE in self.free:
            out.append(f"{EXPOSURE} against every emission ({listed}): the images fix only their product; fix the exposure (of one view) or one emission to resolve it")
        if WHITE_BALANCE in self.free:
            out.append(f"{WHITE_BALANCE} against the emissions' colour ({listed}): the images fix only their product per channel; fix the white balance or one emission's colour to resolve it")
        return out


def _per_view(value, views: int, shape: tuple, key: str) -> torch.Tensor:
    """A sensor option as (V, *shape) float64: one value for all views, or one per view."""
    try:
        t = torch.as_tensor(value, dtype=torch.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"sensor option {key} must be numbers, got {value!r}") from None
    if tuple(t.shape) == shape:
        t = t.expand(views, *shape)
    if tuple(t.shape) != (views, *shape) or not bool(torch.isfinite(t).all()):
        raise ParameterError(f"sensor option {key} must be {'a number' if not shape else 'an RGB triple'} or one per view ({views}), got shape {tuple(t.shape)}")
    return t.clone()


def photograph(radiance: torch.Tensor, exposure: float = 1.0, white_balance=(1.0, 1.0, 1.0), response="srgb") -> torch.Tensor:
    """What a camera with this sensor stores of ``radiance`` (H, W, 3) linear: ``response(exposure
    * white_balance * radiance)``, clipped to [0, 1] (saturation), as (H, W, 3) float32 encoded
    values; :func:`invrender.io.images.write_photo` quantizes and writes them (8-bit JPEG or PNG,
    16-bit PNG). The inverse of the model a fit with a free sensor assumes; for synthetic
    photographs and tests."""
    from invrender.io.response import response as make_response

    gains = float(exposure) * torch.as_tensor(white_balance, dtype=torch.float64).reshape(3)
    linear = (torch.as_tensor(radiance).detach().double() * gains).clamp(0.0, 1.0)
    return make_response(response).encode(linear).clamp(0.0, 1.0).float()


def synthetic_photograph(scene, path, exposure: float = 1.0, white_balance=(1.0, 1.0, 1.0), *, spp: int = 1024, max_depth: int = 5, seed: int = 0,
                         response="srgb", bits: int = 8, quality: int = 95, subsampling: str = "4:4:4") -> torch.Tensor:  # fmt: skip
    """Photograph ``scene`` as a camera would: render it (``spp``, ``max_depth``, ``seed``), apply
    the sensor (:func:`photograph`: exposure, white balance, clipping, ``response``) and write the
    quantized file ``path`` (:func:`invrender.io.images.write_photo`: JPEG or PNG). Returns the
    (H, W, 3) linear render it was made from. For round trips: a fit of the file with the
    sensor free should recover ``exposure`` and ``white_balance``."""
    from invrender.estimators import render
    from invrender.io.images import write_photo

    radiance = render(scene, spp=spp, max_depth=max_depth, seed=seed, progress=False)
    write_photo(path, photograph(radiance, exposure, white_balance, response), bits=bits, quality=quality, subsampling=subsampling)
    return radiance
