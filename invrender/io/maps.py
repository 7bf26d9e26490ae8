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


def write_environment(folder, texels: torch.Tensor, stderr: torch.Tensor | None = None, resolution: torch.Tensor | None = None) -> list:
    """Write a recovered environment map into ``folder`` (made if absent): ``map.exr`` the map
    (h, w, 3), ``stderr.exr`` its standard errors (h, w, 3) and ``resolution.png`` the
    identifiability map (each texel's smallest resolution (h, w, 3) over the channels, viridis: 0
    dark blue, set by the prior, to 1 yellow, set by the images), those given. Returns the paths."""
    from pathlib import Path

    from invrender.io.images import write_image

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / "map.exr"]
    write_image(paths[0], texels.detach())
    if stderr is not None:
        paths.append(folder / "stderr.exr")
        write_image(paths[-1], stderr.detach())
    if resolution is not None:
        paths.append(folder / "resolution.png")
        write_count_map(paths[-1], resolution.detach().amin(2), top=1.0)
    return paths
