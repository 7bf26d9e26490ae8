"""Which solver a fit runs: ``solver="auto"`` (the default of :func:`invrender.fit`) decided from
what the fitted parameters are and which settings the call gave.

The rule (:func:`choose_solver`), first match wins; its one-line reason is
:attr:`~invrender.inverse.fit.FitResult.solver_reason` and the fit's first progress line:

1. **A setting only Adam has** -> ``"adam"``: a loss other than ``relative_l2`` (the least-squares
   solvers minimize that one), ``control_variate``, ``decorrelate=False`` (they always decorrelate),
   an unbounded depth (``max_depth`` -1: they need a finite polynomial), an integrator that is not
   a polynomial in the parameters (``radiosity``), or one of Adam's own settings given (``steps``,
   ``lr``, ...: :data:`ADAM_SETTINGS`) without any of the least-squares solvers'
   (:data:`LEAST_SQUARES_SETTINGS`).
2. **Only the sensor fitted** -> ``"adam"`` (the least-squares solvers need a scene parameter).
3. **One environment map's texels alone** (``NAME.emission`` of an ``envmap``, an (h, w, 3) map,
   nothing else fitted, no least-squares setting given) -> ``"transport_matrix"``: every image is
   linear in the texels, one non-negative regularized linear solve on the transport matrix
   (:func:`invrender.inverse.map_fit.fit_map`) recovers them.
4. **One environment map's texels and material reflectances** (RGB triples path records represent;
   no least-squares setting given) -> ``"joint"``: the images are bilinear, the transport-matrix
   solve of the map alternates with lm on path records of the reflectances
   (:func:`invrender.inverse.joint_fit.fit_joint`; refused when nothing known fixes the scale
   between them).
5. **Every parameter a polynomial factor of the path weights** (albedos, k_s, emissions, the
   sensor's gains beside them) -> ``"lm"`` on path records, unless a texture has more than
   :data:`LM_MAX_TEXELS` texels (the records and the dense normal equations grow with them; an
   8 x 16 map took lm longer than Adam) -> ``"adam"``.
6. **A parameter records cannot represent** (a roughness) -> ``"lm"`` on re-traced renders, unless
   that cannot fit it (the sensor fitted beside it, or more forward-mode renders per Jacobian than
   :data:`~invrender.inverse.retraced.MAX_RENDERS`) -> ``"adam"``.

A solver named explicitly is taken as given (``"transport_matrix"`` and ``"joint"`` checked to apply).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from invrender.errors import ParameterError
from invrender.inverse import retraced
from invrender.inverse.joint_fit import joint_names
from invrender.inverse.sensor import Sensor, is_sensor
from invrender.registry import EMITTERS
from invrender.scene.scene import Scene

#: every solver name ``FitSettings.solver`` takes
SOLVERS = ("auto", "adam", "lm", "gauss_newton", "transport_matrix", "joint")
#: settings only Adam reads: one given (without a least-squares one) asks for Adam
#: (not ``spp_final``: the transport matrix's samples too)
ADAM_SETTINGS = ("steps", "lr", "lr_emission", "lr_sensor", "lr_normals", "lr_final", "beta2", "estimator", "plateau_window")
#: settings only the least-squares solvers read: one given rules out the transport matrix and
#: Adam's own settings choosing Adam
LEAST_SQUARES_SETTINGS = ("rounds", "precision", "prior_weight", "smoothness")
#: texels of one textured parameter up to which lm on path records is chosen (beyond: Adam)
LM_MAX_TEXELS = 64


@dataclass(frozen=True)
class SolverChoice:
    """A fit's solver and why, in one line."""

    solver: str
    reason: str


def choose_solver(scene: Scene, names: list[str], settings, given=()) -> SolverChoice:
    """The solver of a fit of ``names`` (scene and sensor parameters) of ``scene`` with
    :class:`~invrender.inverse.fit.FitSettings` ``settings``; ``given``: the setting names the
    call gave (the rest are defaults). The rule: module docstring."""
    if settings.solver == "transport_matrix":
        why = _not_a_lone_map(scene, names)
        if why:
            raise ParameterError(f"solver 'transport_matrix' fits one environment map's texels alone: {why}")
    if settings.solver == "joint" and joint_names(scene, names) is None:
        raise ParameterError(f"solver 'joint' fits one environment map's texels with material reflectances (RGB triples), got {', '.join(names)}")
    if settings.solver != "auto":
        return SolverChoice(settings.solver, f"solver {settings.solver!r} asked for")
    given = set(given)
    why = _adam_only(settings, given)
    if why:
        return SolverChoice("adam", why)
    scene_names = [n for n in names if not is_sensor(n)]
    if not scene_names:
        return SolverChoice("adam", "only the sensor is fitted (the least-squares solvers need a scene parameter)")
    lsq = sorted(given & set(LEAST_SQUARES_SETTINGS))
    if _not_a_lone_map(scene, names) is None and not lsq:
        h, w = scene.params[names[0]].shape[:2]
        return SolverChoice("transport_matrix", f"{names[0]} is an environment map ({h}x{w} texels) fitted alone: the images are linear in it, one solve on the transport matrix")
    joint = joint_names(scene, names)
    if joint is not None and not lsq:
        h, w = scene.params[joint[0]].shape[:2]
        return SolverChoice("joint", f"{joint[0]} is an environment map ({h}x{w} texels) fitted with {', '.join(joint[1])}: the images are bilinear, the transport-matrix solve of the map alternates with lm on path records")
    obstacle = retraced.record_obstacle(scene, scene_names)
    if obstacle is None:
        big = [(n, _texels(scene, n)) for n in scene_names if _texels(scene, n) > LM_MAX_TEXELS]
        if big:
            return SolverChoice("adam", f"{big[0][0]} has {big[0][1]} texels: lm's path records and normal equations grow with them (lm up to {LM_MAX_TEXELS})")
        return SolverChoice("lm", "every parameter is a polynomial factor of the path weights: lm on path records")
    try:
        retraced.check(scene, scene_names, Sensor.make(1, names, None), "lm")
    except ParameterError as e:
        return SolverChoice("adam", f"{obstacle}, and {e}".split("; ")[0])
    return SolverChoice("lm", f"{obstacle}: lm on re-traced renders")


def _adam_only(settings, given: set) -> str | None:
    """Why only Adam can run these settings (rule 1), or None."""
    if settings.loss != "relative_l2":
        return f"loss {settings.loss!r}: the least-squares solvers minimize relative_l2 only"
    if settings.control_variate:
        return "control_variate is Adam's"
    if not settings.decorrelate:
        return "decorrelate=False is Adam's (the least-squares solvers always decorrelate)"
    model = settings.model
    if model.terms_kept < 1:
        return "max_depth -1 (unbounded): the least-squares solvers need a finite depth"
    if model.not_recordable:
        return f"integrator {model.name!r}: {model.not_recordable}"
    adam = [n for n in ADAM_SETTINGS if n in given]
    if adam and not given & set(LEAST_SQUARES_SETTINGS):
        return f"{', '.join(adam)} given: Adam's setting{'s' if len(adam) > 1 else ''}"
    return None


def _texels(scene: Scene, name: str) -> int:
    """Texels of a scene parameter (1 for an RGB value)."""
    shape = scene.params[name].shape
    return math.prod(shape[:-1]) if len(shape) == 3 else 1


def _not_a_lone_map(scene: Scene, names: list[str]) -> str | None:
    """Why ``names`` is not one environment map's texels alone, or None when it is."""
    if len(names) != 1:
        return f"{len(names)} parameters fitted ({', '.join(names)})"
    owner, _, key = names[0].rpartition(".")
    if key != "emission" or owner not in scene.emitters:
        return f"{names[0]} is not an emitter's emission"
    kind = scene.emitter_spec(scene.emitters.index(owner)).type
    if not getattr(EMITTERS[kind], "texel_lookup", False):
        return f"{owner} is an emitter of type {kind!r}, not an environment map"
    if scene.params[names[0]].ndim != 3:
        return f"{names[0]} is one RGB value, not an (h, w, 3) map"
    return None
