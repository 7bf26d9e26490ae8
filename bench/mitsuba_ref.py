"""Mitsuba 3 as an optional reference: the same Cornell box, rendered and timed by Mitsuba.

Nothing here is needed by invrender or its tests. To install on Debian bookworm (Mitsuba's LLVM
CPU variant needs a libLLVM newer than bookworm's default 15):

    apt-get install -y libllvm19
    pip install mitsuba==3.9.1 drjit
    export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so    # set automatically below if unset

Dr.Jit renders asynchronously, so every timing calls ``dr.eval(img); dr.sync_thread()`` before it
stops the clock.
"""

from __future__ import annotations

import glob
import os
import re
import time

VARIANT = "llvm_ad_rgb"
_mi = _dr = None


def available() -> bool:
    """True when Mitsuba 3 imports and its ``llvm_ad_rgb`` variant can be set; never raises."""
    global _mi, _dr
    if _mi is not None:
        return True
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        found = glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM-*.so") + glob.glob("/usr/lib/llvm-*/lib/libLLVM-*.so")
        versions = {int(m.group(1)): f for f in found if (m := re.search(r"libLLVM-(\d+)\.so$", f))}
        if versions:
            os.environ["DRJIT_LIBLLVM_PATH"] = versions[max(versions)]
    try:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(VARIANT)
    except Exception:
        return False
    _mi, _dr = mi, dr
    return True


def version() -> str:
    return _mi.__version__ if available() else "unavailable"


def cornell_scene(width: int, height: int, spp: int, max_depth: int, integrator: str = "path"):
    """Mitsuba's own ``cornell_box()`` with a box pixel filter, the given film and integrator."""
    mi = _mi
    d = mi.cornell_box()
    d["sensor"]["film"]["width"], d["sensor"]["film"]["height"] = width, height
    d["sensor"]["film"]["rfilter"] = {"type": "box"}
    d["sensor"]["sampler"] = {"type": "independent", "sample_count": spp}
    d["integrator"] = {"type": integrator, "max_depth": max_depth}
    return mi.load_dict(d)


def render(scene, spp: int, seed: int = 0):
    """(H, W, 3) numpy float32 linear RGB, evaluated and synchronized."""
    img = _mi.render(scene, spp=spp, seed=seed)
    _dr.eval(img)
    _dr.sync_thread()
    return img.numpy()[..., :3]


def time_render(scene, spp: int, seed: int = 0) -> float:
    """Seconds for one forward render, the clock stopped after Dr.Jit has finished."""
    start = time.perf_counter()
    render(scene, spp, seed)
    return time.perf_counter() - start


def albedo_keys(params) -> dict[str, str]:
    """Mitsuba parameter keys of the Cornell box's white/red/green albedos and the light radiance."""
    keys = {}
    for name, key in (("white", "white.reflectance.value"), ("red", "red.reflectance.value"), ("green", "green.reflectance.value"), ("light", "light.emitter.radiance.value")):
        if key in params:
            keys[name] = key
    return keys


def gradient_seconds(width: int, height: int, spp: int, max_depth: int, integrator: str = "prb", seed: int = 0) -> float:
    """Seconds for one gradient of an L2 loss (against a fixed target) w.r.t. the three albedos and
    the light radiance, with Mitsuba's ``prb`` (path replay) or plain-AD ``path`` integrator."""
    mi, dr = _mi, _dr
    scene = cornell_scene(width, height, spp, max_depth, integrator)
    target = mi.TensorXf(render(scene, spp, seed + 1000))
    params = mi.traverse(scene)
    keys = albedo_keys(params)
    for k in keys.values():
        dr.enable_grad(params[k])
    params.update()

    def once():
        start = time.perf_counter()
        img = mi.render(scene, params, spp=spp, seed=seed)
        loss = dr.mean(dr.square(img - target))
        dr.backward(loss)
        grads = [dr.grad(params[k]) for k in keys.values()]
        dr.eval(*grads)
        dr.sync_thread()
        return time.perf_counter() - start

    once()  # compiles the kernels
    return once()
