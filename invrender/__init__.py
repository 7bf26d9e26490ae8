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

Each name is imported on first use (PEP 562), so ``import invrender`` itself imports no torch and
the command line's ``--help`` answers at once; the plugin registries import the built-in plugins
on their first use (:mod:`invrender.registry`).
"""

import importlib

__version__ = "0.1.0"

#: the public API: name -> "module:attribute" (or "module" for a module), imported on first use
#: (PEP 562), so that ``import invrender`` (and the command line's --help) imports no torch;
#: ``import invrender as ir; ir.render(...)`` and ``from invrender import fit`` work as if eager
_API = {
    "load_scene": "invrender.scene:load_scene",
    "render": "invrender.estimators:render",
    "fit": "invrender.inverse.fit:fit",
    "FitResult": "invrender.inverse.fit:FitResult",
    "gradcheck": "invrender.inverse.gradcheck:gradcheck",
    "identifiability": "invrender.inverse.identifiability:identifiability",
    "read_image": "invrender.io:read_image",
    "write_image": "invrender.io:write_image",
    "record_paths": "invrender.estimators.records:record_paths",
    "PathRecords": "invrender.estimators.records:PathRecords",
    "Camera": "invrender.scene.camera:Camera",
    "load_cameras": "invrender.scene.formats.cameras:load_cameras",
    "Material": "invrender.scene.materials:Material",
    "gradient_study": "invrender.study:gradient_study",
    "GradientStudy": "invrender.study:GradientStudy",
    "GradientConfig": "invrender.study:GradientConfig",
    "AdaptiveSettings": "invrender.core.adaptive:AdaptiveSettings",
    "AdaptiveResult": "invrender.core.adaptive:AdaptiveResult",
    "radiosity": "invrender.plugins.integrators.radiosity:radiosity",
    "RadiositySolution": "invrender.radiosity_solver:RadiositySolution",
    "InvRenderError": "invrender.errors:InvRenderError",
    "SceneError": "invrender.errors:SceneError",
    "ImageError": "invrender.errors:ImageError",
    "ParameterError": "invrender.errors:ParameterError",
    "UnknownParameterError": "invrender.errors:UnknownParameterError",
    "BaselineError": "invrender.errors:BaselineError",
    # modules
    "integrators": "invrender.plugins.integrators",
    "lighting": "invrender.inverse.lighting",
    "emitters": "invrender.plugins.emitters",
    "materials": "invrender.plugins.bsdfs",
    "baseline": "invrender.baseline",  # pyrender picks its OpenGL platform when imported
}


def __getattr__(name):
    target = _API.get(name)
    if target is None:
        return _submodule(name)
    module, _, attribute = target.partition(":")
    value = importlib.import_module(module)
    if attribute:
        value = getattr(value, attribute)
    globals()[name] = value  # the next access is a plain attribute
    return value


def _submodule(name):
    """``invrender.NAME``, a subpackage or module (``ir.io``, ``ir.scene``, ...), imported as the
    eager package had them."""
    if not name.startswith("_"):
        try:
            return importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{name}":
                raise  # the module exists but needs a package that is missing
    raise AttributeError(f"module 'invrender' has no attribute {name!r}")


def __dir__():
    return sorted({*globals(), *_API})


__all__ = [
    "load_scene", "render", "fit", "gradcheck", "read_image", "write_image", "FitResult", "Camera", "load_cameras", "Material", "integrators",
    "radiosity", "RadiositySolution", "AdaptiveSettings", "AdaptiveResult", "record_paths", "PathRecords", "identifiability", "lighting", "gradient_study", "GradientStudy", "GradientConfig",
    "InvRenderError", "SceneError", "ImageError", "ParameterError", "UnknownParameterError", "BaselineError",
]  # fmt: skip
