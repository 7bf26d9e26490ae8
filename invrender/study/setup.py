"""What a study starts from: its own copy of the scene, the point where gradients are taken (or
fits start), and its target image. Shared by gradient studies and fit studies."""

from __future__ import annotations

import math

import torch

from invrender.estimators import render
from invrender.errors import ParameterError
from invrender.scene.scene import Scene
from invrender.study.configs import GradientConfig


def study_target(scene: Scene, target, target_spp: int, seed: int, config: GradientConfig) -> tuple[torch.Tensor, str]:
    """The target image (H, W, 3) and how it was made."""
    if target is not None:
        from invrender.inverse.targets import load_views  # the checks fit applies to its targets

        return load_views(scene, target, None)[0][1], "given"
    model = config.model  # the configuration's expected image
    options = {k: v for k, v in model.render_kwargs().items() if k != "estimator"}
    with torch.no_grad():
        image = render(scene, spp=target_spp, seed=seed, progress=False, **options)
    return image, f"rendered: {model.integrator}, {target_spp} spp" + "".join(f", {k}={v}" for k, v in model.options)


def move_to(scene: Scene, names: list[str], at) -> None:
    """Set the studied parameters of ``scene`` (in place) to where the gradient is taken."""
    from invrender.recipes import apply_init, set_param

    if isinstance(at, dict):
        apply_init(scene, names, at)
        return
    if isinstance(at, bool) or not isinstance(at, (int, float)) or not math.isfinite(at) or at <= 0:
        raise ParameterError(f"at must be a positive factor or a dict of parameter values, got {at!r}")
    for n in names:
        set_param(scene, n, scene.params[n].detach() * at)
