"""Orthonormal shading frames: world directions to and from a frame whose z axis is a normal.

BSDFs that are not rotationally trivial (the GGX lobe, refraction) work in the local frame, where
``cos(theta) = z``. The tangents come from Duff et al., "Building an Orthonormal Basis, Revisited"
(JCGT 6(1), 2017): branch-free and continuous except where ``n`` points straight down -z.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.vec import dot


@dataclass(frozen=True)
class Frame:
    """N orthonormal frames (s, t, n), each (N, 3)."""

    s: torch.Tensor
    t: torch.Tensor
    n: torch.Tensor

    @staticmethod
    def from_normal(n: torch.Tensor) -> "Frame":
        """Frames whose z axis is the unit normal ``n`` (N, 3)."""
        sign = torch.where(n[:, 2] >= 0, 1.0, -1.0)
        a = -1.0 / (sign + n[:, 2])
        b = n[:, 0] * n[:, 1] * a
        s = torch.stack([1.0 + sign * n[:, 0] * n[:, 0] * a, sign * b, -sign * n[:, 0]], dim=1)
        t = torch.stack([b, sign + n[:, 1] * n[:, 1] * a, -n[:, 1]], dim=1)
        return Frame(s, t, n)

    def to_local(self, v: torch.Tensor) -> torch.Tensor:
        """World vectors (N, 3) -> local coordinates (N, 3)."""
        return torch.stack([dot(v, self.s), dot(v, self.t), dot(v, self.n)], dim=1)

    def to_world(self, v: torch.Tensor) -> torch.Tensor:
        """Local coordinates (N, 3) -> world vectors (N, 3)."""
        return v[:, 0:1] * self.s + v[:, 1:2] * self.t + v[:, 2:3] * self.n
