"""False-colour maps of per-pixel quantities (sample counts of adaptive sampling) as PNG files."""

from __future__ import annotations

import numpy as np
import torch
from PIL import Image

from invrender.io.atomic import atomic_file


def write_count_map(path, counts: torch.Tensor, top: float | None = None) -> None:
    """Write ``counts`` (H, W) >= 0 to the PNG ``path`` as a viridis map, 0 dark blue to the
    largest count (or ``top``) yellow, one PNG pixel per image pixel (atomically)."""
    from matplotlib import colormaps

    values = counts.detach().to("cpu", torch.float64).numpy()
    if top is None:
        top = float(values.max()) if values.size and values.max() > 0 else 1.0
    values = np.clip(values, 0.0, top)
    rgb = colormaps["viridis"](values / top)[..., :3]
    with atomic_file(path) as f:
        Image.fromarray(np.round(rgb * 255.0).astype(np.uint8), mode="RGB").save(f, format="PNG")
