"""invrender: Monte Carlo rendering of Kajiya's rendering equation ``I = g(eps + M I)`` on torch
tensors, differentiable in emission eps and reflectance rho.

Public API::

    import invrender as ir
    scene = ir.load_scene("cornell_box", resolution=(64, 64))
    img = ir.render(scene, spp=64, max_depth=8, seed=0)     # (H, W, 3) float32, linear
    ir.write_image("out.exr", img)
    img = ir.render(scene, ir.integrators.Whitted(max_depth=6))   # an integrator object
    res = ir.render(scene, spp=64, adaptive=ir.AdaptiveSettings(rounds=2), return_counts=True)   # adaptive sampling
    res = ir.fit(scene, target, params=["red.reflectance", "light.emission"])   # inverse rendering
    views = ir.load_cameras("capture/transforms.json")       # (camera, image, (w, h)) per view; or COLMAP
    sh = ir.lighting.fit_sh(scene, targets, emitter="sky", order=2, cameras=cams)   # SH lighting coefficients
    study = ir.gradient_study(scene, ["red.reflectance", "light.emission"])   # gradient variance and bias
    base = ir.baseline.pyrender_render(scene)               # the rasterized Utah baseline
"""

from invrender import emitters, materials  # noqa: F401  (registers the built-in emitters and materials)
from invrender.errors import BaselineError, ImageError, InvRenderError, ParameterError, SceneError, UnknownParameterError
from invrender.inverse.fit import FitResult, fit
from invrender.inverse.identifiability import identifiability
from invrender.inverse.gradcheck import gradcheck
from invrender.inverse import lighting
from invrender.io import read_image, write_image
from invrender.diff import render
from invrender.diff.records import PathRecords, record_paths
from invrender.scene import load_scene
from invrender.scene.camera import Camera
from invrender.scene.formats.cameras import load_cameras
from invrender.scene.materials import Material
from invrender.study import GradientConfig, GradientStudy, gradient_study
from invrender.transport import integrators
from invrender.transport.adaptive import AdaptiveResult, AdaptiveSettings
from invrender.transport.integrators.radiosity import radiosity
from invrender.transport.radiosity import RadiositySolution

__version__ = "0.1.0"


def __getattr__(name):
    # ir.baseline is imported on first use: pyrender picks its OpenGL platform when imported
    if name == "baseline":
        import importlib

        return importlib.import_module("invrender.baseline")
    raise AttributeError(f"module 'invrender' has no attribute {name!r}")


__all__ = [
    "load_scene", "render", "fit", "gradcheck", "read_image", "write_image", "FitResult", "Camera", "load_cameras", "Material", "integrators",
    "radiosity", "RadiositySolution", "AdaptiveSettings", "AdaptiveResult", "record_paths", "PathRecords", "identifiability", "lighting", "gradient_study", "GradientStudy", "GradientConfig",
    "InvRenderError", "SceneError", "ImageError", "ParameterError", "UnknownParameterError", "BaselineError",
]  # fmt: skip
