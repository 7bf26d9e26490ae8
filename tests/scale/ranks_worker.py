"""Run under torchrun by tests/scale/test_ranks.py: the Python API inside an initialized process
group. Writes (rank 0 only, through invrender's own writer) the image and gradients of each
estimator, a decorrelated gradient, and whether a gradient study refused to run."""

import sys

import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.io.atomic import atomic_file
from invrender.study import gradient_study


def decorrelated(scene) -> torch.Tensor:
    """A decorrelated gradient (``backpropagate``: a fit's step) of red's reflectance."""
    from invrender.estimators import backpropagate
    from invrender.core.driver import RenderSettings
    from invrender.plugins.integrators import make_integrator

    rho = scene.params["red.reflectance"].requires_grad_(True)
    backpropagate(scene, torch.ones(scene.height, scene.width, 3), make_integrator("path"), RenderSettings(spp=8, seed=1, progress=False), "replay")
    grad = rho.grad.clone()
    rho.grad = None
    rho.requires_grad_(False)
    return grad


def main(out: str) -> None:
    torch.distributed.init_process_group("gloo")
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    target = ir.render(scene, spp=32, seed=7, progress=False)
    results = {"target": target}
    for estimator in ("replay", "autodiff"):
        rho = scene.params["red.reflectance"].requires_grad_(True)
        eps = scene.params["light.emission"].requires_grad_(True)
        image = ir.render(scene, spp=8, seed=1, estimator=estimator, progress=False)
        ((image - target) ** 2).mean().backward()
        results[estimator] = (image.detach(), rho.grad.clone(), eps.grad.clone())
        rho.grad = eps.grad = None
        rho.requires_grad_(False)
        eps.requires_grad_(False)
    results["backpropagate"] = decorrelated(scene)
    try:
        gradient_study(scene, ["red.reflectance"], spp=[2], trials=2, progress=False)
        results["study"] = "ran"
    except ParameterError as e:
        results["study"] = str(e)
    with atomic_file(out) as f:
        torch.save(results, f)
    torch.distributed.destroy_process_group()


if __name__ == "__main__":
    main(sys.argv[1])
