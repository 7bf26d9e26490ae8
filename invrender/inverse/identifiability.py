"""identifiability(): what a set of target images determines about parameters, without fitting.

From two independent path-record sets at the scene's current values (least_squares.analyse), or,
for parameters path records cannot represent (a roughness; the rule of retraced.py), from
forward-mode renders of two independent seeds (retraced.analyse):
standard errors, correlations and the parameter combinations the targets cannot determine, the
sensor's scale ambiguities named; or, for an environment map, in spherical harmonics
(lighting.fit_sh: which coefficients, and so which orders, the images determine).
"""

from __future__ import annotations

from invrender.estimators.records import record_paths
from invrender.errors import ParameterError
from invrender.inverse import lighting
from invrender.inverse.fit import check_fit_names
from invrender.inverse.targets import load_targets
from invrender.inverse import retraced
from invrender.inverse.least_squares import analyse
from invrender.inverse.sensor import Sensor, is_sensor
from invrender.scene.camera import Camera
from invrender.scene.scene import Scene
from invrender.plugins.integrators import make_integrator


def identifiability(
    scene: Scene, target, params, *, cameras: list[Camera] | None = None, spp: int = 64, max_depth: int = 8, seed: int = 0, integrator: str = "path",
    mask=None, response=None, sensor: dict | None = None, exclude_clipped: bool = True, order: int | None = None, sampler: str = "stratified",
):  # fmt: skip
    """What ``target`` (one image or one per camera) determines about ``params`` at the scene's
    current values, without fitting: standard errors, correlations and the parameter
    combinations the targets cannot determine (a near-singular ``J^T J``; e.g. the scale between an
    emitter's eps and every rho when the emitter is never seen directly), from two independent
    path records of ``spp`` samples (for a roughness, or any parameter records cannot represent:
    two forward-mode renders per parameter and view, retraced.py); with ``sensor.exposure`` or ``sensor.white_balance`` among
    ``params``, the sensor's scale ambiguities against the emissions are named
    (:meth:`~invrender.inverse.sensor.Sensor.ambiguities`). ``mask``, ``response``, ``sensor`` and
    ``exclude_clipped`` as in :func:`fit`; ``sampler`` as in ``render``. Returns an
    :class:`~invrender.inverse.least_squares.Identifiability`.

    ``order``: analyse an environment map in spherical harmonics up to that order instead of per
    texel: ``params`` is then the one envmap's ``NAME.emission``, and the result is the
    :class:`~invrender.inverse.lighting.SHFit` of :func:`~invrender.inverse.lighting.fit_sh`
    (coefficients with standard errors, ``undetermined`` coefficient labels such as
    ``"Y[3,-1]"``, :meth:`~invrender.inverse.lighting.SHFit.undetermined_orders`), at ``spp``
    (``max_depth`` as given; 2 suits a convex object, whose light arrives in one bounce)."""
    names = check_fit_names(scene, params)
    if order is not None:
        return _sh_identifiability(scene, target, names, order, cameras=cameras, spp=spp, max_depth=max_depth, seed=seed, integrator=integrator, sampler=sampler)
    views = load_targets(scene, target, cameras, mask=mask, response=response, exclude_clipped=exclude_clipped)
    sens = Sensor.make(len(views), names, sensor)
    scene_names = [n for n in names if not is_sensor(n)]
    if not scene_names:
        raise ParameterError("identifiability needs a scene parameter among params")
    if retraced.record_obstacle(scene, scene_names) is not None:
        retraced.check(scene, scene_names, sens, "identifiability")
        values = {n: scene.params[n].detach().double() for n in scene_names}
        seeds = [(2 * (seed * len(views) + v), 2 * (seed * len(views) + v) + 1) for v in range(len(views))]
        model = make_integrator(integrator, max_depth=max_depth)
        return retraced.analyse([s for s, _ in views], [t for _, t in views], values, model=model, spp=spp, seeds=seeds, sampler=sampler, sensor=sens)
    recs = [[record_paths(view_scene, scene_names, spp=spp, max_depth=max_depth, seed=2 * (seed * len(views) + v) + half, integrator=integrator, sampler=sampler, progress=False) for v, (view_scene, _) in enumerate(views)] for half in (0, 1)]
    values = {n: scene.params[n].detach().double() for n in scene_names}
    return analyse(recs[0], recs[1], [t for _, t in views], values, sensor=sens, ambiguities=sens.ambiguities(names, scene.params))


def _sh_identifiability(scene: Scene, target, names: list[str], order, **kw) -> lighting.SHFit:
    """fit_sh's determination of the one envmap named in ``names``."""
    emission = [n for n in names if n.endswith(".emission")]
    if len(names) != 1 or not emission:
        raise ParameterError(f"identifiability(order=...) analyses one environment map's emission in spherical harmonics, got params {names}")
    return lighting.fit_sh(scene, target, emission[0].rsplit(".", 1)[0], order, **kw)
