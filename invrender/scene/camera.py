"""The perspective camera, pinhole or thin lens: pixel positions -> primary rays.

Conventions (shared with Mitsuba 3): the camera looks from ``origin`` at ``target``; image x grows to
the camera's right (``forward x up``) and image rows grow downwards, so row 0 is the top of the
image; ``fov`` is the full field of view in degrees along ``fov_axis``.

Off-centre and non-square pinholes (the intrinsics of a calibrated camera): ``principal_point_offset``
(ox, oy) shifts the image window in the image plane by fractions of the image's width and height
(x to the right, y down), as Mitsuba 3's ``principal_point_offset_x/_y``: film position (x, y) sees
what the centred camera sees at (x + ox W, y + oy H), so the optical axis crosses the film at pixel
position (cx, cy) = ((0.5 - ox) W, (0.5 - oy) H). ``pixel_aspect`` = fy / fx is the ratio of the
focal lengths in pixels (1 = square pixels): ``fov`` fixes the angle along ``fov_axis`` and the
other axis's extent is divided by (x) or multiplied by (y) the aspect. A film position is in pixel
units, the top-left corner at (0, 0) and pixel centres at i + 0.5 (COLMAP's convention), so
``fx = W / (2 tan(fov_x / 2))`` and a world point at camera coordinates (right r, down d, depth z)
lands at ``(cx + fx r / z, cy + fy d / z)``: :meth:`Camera.intrinsics` and
:meth:`Camera.from_intrinsics` convert.

The orthographic camera (Mitsuba's ``orthographic``, :class:`OrthographicCamera`): parallel rays
along the view direction from a rectangular window around ``origin``.

The thin lens (Mitsuba's ``thinlens``): with ``aperture_radius`` r > 0, each ray starts at a point
uniformly distributed on the lens, a disk of radius r around ``origin`` in the image plane's
orientation, and passes through the point the pinhole ray meets on the plane of focus, at
``focus_distance`` along the view axis. Points on that plane are sharp; others blur into a disk
(the circle of confusion). r = 0 is the pinhole.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

import torch

from invrender.errors import SceneError
from invrender.validate import FLOAT32_MAX
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
        principal_point_offset: (ox, oy), the image window's shift in fractions of the image's
            width and height (x right, y down; module docstring); (0, 0) = centred.
        pixel_aspect: fy / fx, the ratio of the focal lengths in pixels, > 0 (1 = square pixels).
    """

    origin: tuple[float, float, float] = (0.0, 0.0, 3.9)
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov: float = 39.3077
    fov_axis: str = "smaller"
    aperture_radius: float = 0.0
    focus_distance: float = 1.0
    principal_point_offset: tuple[float, float] = (0.0, 0.0)
    pixel_aspect: float = 1.0

    def __post_init__(self):
        for name in ("origin", "target", "up"):
            value = tuple(float(x) for x in getattr(self, name))
            if len(value) != 3:
                raise SceneError(f"camera {name} must have 3 components, got {len(value)}")
            if not all(_is_finite(x) for x in value):  # rays are float32: beyond its range is infinity too
                raise SceneError(f"camera {name} must be 3 finite numbers (|x| <= {FLOAT32_MAX:.4g}), got {list(value)}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "fov", float(self.fov))
        if not (0.0 < self.fov < 180.0):
            raise SceneError(f"camera fov must be in (0, 180) degrees, got {self.fov}")
        for name in ("aperture_radius", "focus_distance", "pixel_aspect"):
            value = getattr(self, name)
            if not _is_finite(value):
                raise SceneError(f"camera {name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        offset = tuple(self.principal_point_offset)
        if len(offset) != 2 or not all(_is_finite(x) for x in offset):
            raise SceneError(f"camera principal_point_offset must be 2 finite numbers (fractions of the image width and height), got {self.principal_point_offset!r}")
        object.__setattr__(self, "principal_point_offset", tuple(float(x) for x in offset))
        if self.pixel_aspect <= 0:
            raise SceneError(f"camera pixel_aspect (fy / fx) must be positive, got {self.pixel_aspect:g}")
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
        """``tan`` of the half field of view along image x and y for a ``width x height`` film
        (of the centred window: the principal point offset shifts it, not its size)."""
        axis = self.fov_axis
        if axis == "smaller":
            axis = "x" if width <= height else "y"
        elif axis == "larger":
            axis = "x" if width >= height else "y"
        t = math.tan(math.radians(self.fov) / 2.0)
        if axis == "x":
            return t, t * height / width / self.pixel_aspect
        return t * width / height * self.pixel_aspect, t

    def intrinsics(self, width: int, height: int) -> tuple[float, float, float, float]:
        """Pinhole intrinsics ``(fx, fy, cx, cy)`` in pixels for a ``width x height`` film: the
        focal lengths and the principal point, in film coordinates (module docstring)."""
        tx, ty = self.tan_half_fov(width, height)
        ox, oy = self.principal_point_offset
        return width / (2.0 * tx), height / (2.0 * ty), (0.5 - ox) * width, (0.5 - oy) * height

    @classmethod
    def from_intrinsics(cls, fx: float, fy: float, cx: float, cy: float, width: int, height: int, **pose) -> "Camera":
        """The pinhole with intrinsics ``(fx, fy, cx, cy)`` (pixels, as :meth:`intrinsics` gives
        them) on a ``width x height`` film; ``pose``: ``origin``, ``target``, ``up`` (and any other
        field). The field of view is stated along x."""
        for name, value in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)):
            if not _is_finite(value):
                raise SceneError(f"camera intrinsics: {name} must be a finite number, got {value!r}")
        if fx <= 0 or fy <= 0:
            raise SceneError(f"camera intrinsics: focal lengths must be positive, got fx {fx:g}, fy {fy:g}")
        fov = math.degrees(2.0 * math.atan(width / (2.0 * fx)))
        return cls(fov=fov, fov_axis="x", pixel_aspect=fy / fx, principal_point_offset=(0.5 - cx / width, 0.5 - cy / height), **pose)

    @property
    def is_pinhole(self) -> bool:
        return self.aperture_radius == 0.0

    def cropped(self, width: int, height: int, offset: tuple[int, int], size: tuple[int, int]) -> "Camera":
        """The camera whose ``size`` (w, h) film sees exactly the crop window at pixel ``offset``
        (x, y) of this camera's ``width x height`` film (Mitsuba's crop window: the projection of
        the full film is kept): the same focal lengths in pixels, the principal point moved by the
        offset. The lens and pose are kept."""
        fx, fy, cx, cy = self.intrinsics(width, height)
        w, h = size
        fov = math.degrees(2.0 * math.atan(w / (2.0 * fx)))
        return dataclasses.replace(self, fov=fov, fov_axis="x", pixel_aspect=fy / fx, principal_point_offset=(0.5 - (cx - offset[0]) / w, 0.5 - (cy - offset[1]) / h))

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
        ox, oy = self.principal_point_offset  # (0, 0) adds exact zeros: a centred camera's rays are unchanged
        sx = (2.0 * film_xy[:, 0] / width + 2.0 * ox - 1.0) * tx
        sy = (1.0 - 2.0 * film_xy[:, 1] / height - 2.0 * oy) * ty
        d = sx[:, None] * right + sy[:, None] * up + forward  # 1 along the view axis
        o = torch.tensor(self.origin, dtype=torch.float32, device=film_xy.device).expand_as(d)
        if self.is_pinhole or u_lens is None:
            return o, normalize(d)
        # thin lens: from a point on the lens disk through the pinhole ray's point on the focal plane
        disk = self.aperture_radius * concentric_disk(u_lens)
        lens = o + disk[:, 0:1] * right + disk[:, 1:2] * up
        focus = o + self.focus_distance * d
        return lens, normalize(focus - lens)


@dataclass(frozen=True)
class OrthographicCamera(Camera):
    """A parallel projection (Mitsuba's ``orthographic``): every ray leaves a point of the image
    window, a rectangle in the plane through ``origin`` facing ``target``, along the view direction.

    Attributes:
        extent: (ex, ey), world units: the window spans ``+-ex`` along the image's x (right) and
            ``+-ey * height / width`` along its y (up), as Mitsuba's camera space ``[-1, 1] x
            [-1 / aspect, 1 / aspect]`` scaled by its to_world's x and y scales. Both > 0.
    ``fov``, ``fov_axis``, the lens and the principal point offset do not apply (the lens and the
    offset must be left at their defaults).
    """

    extent: tuple[float, float] = (1.0, 1.0)

    def __post_init__(self):
        super().__post_init__()
        extent = tuple(self.extent)
        if len(extent) != 2 or not all(_is_finite(x) and x > 0 for x in extent):
            raise SceneError(f"orthographic camera extent must be 2 positive numbers (world units), got {self.extent!r}")
        object.__setattr__(self, "extent", tuple(float(x) for x in extent))
        if self.aperture_radius != 0.0 or self.principal_point_offset != (0.0, 0.0) or self.pixel_aspect != 1.0:
            raise SceneError("an orthographic camera has no lens, principal point offset or pixel aspect")

    def cropped(self, width: int, height: int, offset: tuple[int, int], size: tuple[int, int]) -> "Camera":
        """Not available: an orthographic camera has no principal point offset to move."""
        raise SceneError("a crop window needs a perspective or thinlens camera; the orthographic camera cannot be cropped")

    def generate_rays(self, film_xy: torch.Tensor, width: int, height: int, u_lens: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Parallel rays from the image window (see :meth:`Camera.generate_rays` for the arguments)."""
        right, up, forward = (v.to(film_xy.device, torch.float32) for v in self.frame())
        ex, ey = self.extent[0], self.extent[1] * height / width
        sx = (2.0 * film_xy[:, 0] / width - 1.0) * ex
        sy = (1.0 - 2.0 * film_xy[:, 1] / height) * ey
        o = torch.tensor(self.origin, dtype=torch.float32, device=film_xy.device) + sx[:, None] * right + sy[:, None] * up
        return o, forward.expand_as(o).contiguous()


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


def _is_finite(value) -> bool:
    """A real number (not a bool) that is finite in float32, the rays' precision."""
    return not isinstance(value, bool) and isinstance(value, numbers.Real) and math.isfinite(value) and abs(value) <= FLOAT32_MAX


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
