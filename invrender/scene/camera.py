"""The perspective camera, pinhole or thin lens: pixel positions -> primary rays.

Conventions (shared with Mitsuba 3): the camera looks from ``origin`` at ``target``; image x grows to
the camera's right (``forward x up``) and image rows grow downwards, so row 0 is the top of the
image; ``fov`` is the full field of view in degrees along ``fov_axis``.

The thin lens (Mitsuba's ``thinlens``): with ``aperture_radius`` r > 0, each ray starts at a point
uniformly distributed on the lens, a disk of radius r around ``origin`` in the image plane's
orientation, and passes through the point the pinhole ray meets on the plane of focus, at
``focus_distance`` along the view axis. Points on that plane are sharp; others blur into a disk
(the circle of confusion). r = 0 is the pinhole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from invrender.errors import SceneError
from invrender.vec import normalize

FOV_AXES = ("x", "y", "smaller", "larger")


@dataclass(frozen=True)
class Camera:
    """A perspective camera.

    Attributes:
        origin: eye position, world units.
        target: point the camera looks at.
        up: approximate up direction (need not be orthogonal to the view direction).
        fov: full field of view in degrees, measured along ``fov_axis``.
        fov_axis: ``"x"``, ``"y"``, ``"smaller"`` or ``"larger"`` image axis.
        aperture_radius: radius of the thin lens, world units, >= 0 (0 = pinhole).
        focus_distance: distance of the plane of focus along the view axis, world units, > 0.
    """

    origin: tuple[float, float, float] = (0.0, 0.0, 3.9)
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov: float = 39.3077
    fov_axis: str = "smaller"
    aperture_radius: float = 0.0
    focus_distance: float = 1.0

    def __post_init__(self):
        for name in ("origin", "target", "up"):
            value = tuple(float(x) for x in getattr(self, name))
            if len(value) != 3:
                raise SceneError(f"camera {name} must have 3 components, got {len(value)}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "fov", float(self.fov))
        if not (0.0 < self.fov < 180.0):
            raise SceneError(f"camera fov must be in (0, 180) degrees, got {self.fov}")
        for name in ("aperture_radius", "focus_distance"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise SceneError(f"camera {name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.aperture_radius < 0:
            raise SceneError(f"camera aperture_radius must be >= 0 (0 = pinhole), got {self.aperture_radius:g}")
        if self.focus_distance <= 0:
            raise SceneError(f"camera focus_distance must be positive, got {self.focus_distance:g}")
        if self.fov_axis not in FOV_AXES:
            raise SceneError(f"camera fov_axis must be one of {', '.join(FOV_AXES)}, got {self.fov_axis!r}")
        forward = [t - o for t, o in zip(self.target, self.origin)]
        if math.hypot(*forward) == 0.0:
            raise SceneError("camera origin and target coincide")
        cross = _cross(forward, self.up)
        if math.hypot(*cross) < 1e-9 * math.hypot(*forward) * max(math.hypot(*self.up), 1e-30):
            raise SceneError("camera up is parallel to the view direction (or zero)")

    def frame(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Orthonormal camera frame ``(right, up, forward)``, each a float64 tensor of shape (3,)."""
        o = torch.tensor(self.origin, dtype=torch.float64)
        forward = torch.tensor(self.target, dtype=torch.float64) - o
        forward = forward / forward.norm()
        right = torch.linalg.cross(forward, torch.tensor(self.up, dtype=torch.float64))
        right = right / right.norm()
        up = torch.linalg.cross(right, forward)
        return right, up, forward

    def tan_half_fov(self, width: int, height: int) -> tuple[float, float]:
        """``tan`` of the half field of view along image x and y for a ``width x height`` film."""
        axis = self.fov_axis
        if axis == "smaller":
            axis = "x" if width <= height else "y"
        elif axis == "larger":
            axis = "x" if width >= height else "y"
        t = math.tan(math.radians(self.fov) / 2.0)
        if axis == "x":
            return t, t * height / width
        return t * width / height, t

    @property
    def is_pinhole(self) -> bool:
        return self.aperture_radius == 0.0

    def generate_rays(self, film_xy: torch.Tensor, width: int, height: int, u_lens: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Primary rays through continuous film positions.

        Args:
            film_xy: (N, 2) float32 positions in pixel units, x in [0, width) left to right,
                y in [0, height) top to bottom.
            u_lens: (N, 2) uniforms choosing the point on the lens (thin lens only; ignored by a
                pinhole).
        Returns:
            origins (N, 3) and unit directions (N, 3), float32 on ``film_xy``'s device.
        """
        right, up, forward = (v.to(film_xy.device, torch.float32) for v in self.frame())
        tx, ty = self.tan_half_fov(width, height)
        sx = (2.0 * film_xy[:, 0] / width - 1.0) * tx
        sy = (1.0 - 2.0 * film_xy[:, 1] / height) * ty
        d = sx[:, None] * right + sy[:, None] * up + forward  # 1 along the view axis
        o = torch.tensor(self.origin, dtype=torch.float32, device=film_xy.device).expand_as(d)
        if self.is_pinhole or u_lens is None:
            return o, normalize(d)
        # thin lens: from a point on the lens disk through the pinhole ray's point on the focal plane
        disk = self.aperture_radius * concentric_disk(u_lens)
        lens = o + disk[:, 0:1] * right + disk[:, 1:2] * up
        focus = o + self.focus_distance * d
        return lens, normalize(focus - lens)


def concentric_disk(u: torch.Tensor) -> torch.Tensor:
    """Shirley and Chiu's concentric map of the unit square onto the unit disk: (N, 2) -> (N, 2).

    Area-preserving (uniform in, uniform out) and continuous, so stratified lens samples stay
    stratified."""
    a = 2.0 * u[:, 0] - 1.0
    b = 2.0 * u[:, 1] - 1.0
    wide = a.abs() > b.abs()
    r = torch.where(wide, a, b)
    safe = lambda x: torch.where(x == 0, torch.ones_like(x), x)  # noqa: E731
    phi = torch.where(wide, (math.pi / 4) * b / safe(a), math.pi / 2 - (math.pi / 4) * a / safe(b))
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi)], dim=1)


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
