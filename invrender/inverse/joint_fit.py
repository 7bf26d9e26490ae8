"""Joint lighting and materials: an environment map and the reflectances of the objects it lights,
from the same images (``ir.lighting.fit_joint``; ``ir.fit``'s ``solver="auto"`` routes here when
the fitted parameters are one envmap's texels plus reflectances).

**The problem is bilinear.** For a fixed sampling every image is linear in the map's texels ``L``
(the transport matrix, :mod:`invrender.inverse.map_fit`) and a polynomial in the reflectances
``rho`` (path records, :mod:`invrender.estimators.records`): ``I_v = A_v(rho) L``. Neither part alone is
hard, so the fit alternates the two exact sub-solves, each on its own estimator:

(a) with ``rho`` fixed, the map by the non-negative regularized linear solve of the transport
    matrix ``A(rho)`` (:func:`~invrender.inverse.map_fit.fit_map`; the prior's weight by the
    discrepancy principle);
(b) with the map fixed, ``rho`` by Levenberg-Marquardt on two independent record sets
    (:func:`~invrender.inverse.least_squares.solve`), whose polynomial holds the map as a constant.

**Sampling between rounds.** Every round draws the same random numbers (common seeds), and (a)
always samples the map by the *starting* map (the transport matrix does not depend on the map's
values, only on how directions are drawn), so ``A(rho)`` is a deterministic function of ``rho`` and
the alternation a fixed-point iteration of one problem, not a walk between noisy ones. The records
of (b) sample by the current map (their noise changes a little as it does); the rounds stop once
no reflectance channel moved by more than its standard error (:data:`MOVE`): below the noise,
further rounds only exchange one noise for another.

**The global scale.** Scaling the map by ``c`` and every fitted reflectance by ``1/c`` leaves every
once-reflected path unchanged; only paths between two fitted surfaces (weight ``c^(1-k)`` after k
of them) tell them apart, weakly. So the images determine the product ``rho x L``, not the split,
unless something of known value ties the scale: a reflectance of the scene that is not fitted (a
known albedo), another emitter with a known emission (a known light), or pixels that see the map
directly (the background, when not masked). :func:`scale_anchor` names what fixes it (the result's
``scale``); with none the fit is refused in one line asking for one.

The alternation's two objectives differ in their weights (the map's solve is the plain L2 of the
linear images, the records' the ``relative_l2`` of ``fit``); with images the model reproduces,
both vanish at the same point.
"""

from __future__ import annotations

import dataclasses
import time

import torch

from invrender.estimators import render
from invrender.estimators.records import record_paths, record_obstacle
from invrender.estimators.transport_matrix import envmap_of
from invrender.errors import ParameterError
from invrender.inverse.map_fit import MapFit, fit_map
from invrender.inverse.targets import load_targets
from invrender.registry import EMITTERS
from invrender.scene.kinds import kind_of
from invrender.scene.scene import Scene, check_names

#: the rounds stop once no reflectance channel moved by more than this many of its standard errors
MOVE = 1.0
#: the rounds the alternation may take by default
ROUNDS = 10


@dataclasses.dataclass
class JointFit:
    """What :func:`fit_joint` recovered.

    Attributes:
        texels: (h, w, 3) float32 the map (the emitter's units).
        values: reflectance name -> (3,) float32 recovered value.
        std_error: name -> (3,) standard errors of the reflectances (the records' sandwich, given
            the map: the map's own uncertainty is not carried into them).
        map: the last round's :class:`~invrender.inverse.map_fit.MapFit` (weights, standard errors
            and resolution of the texels, given the reflectances).
        scale: what fixes the global scale between the map and the reflectances (one line).
        rounds: alternation rounds taken.
        converged: whether the last round moved every reflectance channel by less than
            :data:`MOVE` standard errors (else the rounds ran out).
        history: per round ``{"round", "values", "loss", "moved", "seconds"}`` (``loss``: the
            records' mean squared relative residual; ``moved``: the largest change one alternation
            makes to a reflectance channel, in its standard errors).
        seconds: ``{"map": ..., "records": ...}`` summed over the rounds.
    """

    texels: torch.Tensor
    values: dict
    std_error: dict
    map: MapFit
    scale: str
    rounds: int
    converged: bool
    history: list
    seconds: dict

    def describe(self) -> str:
        """One line: rounds, convergence, the scale's anchor, the last map solve's line."""
        state = "converged" if self.converged else "NOT converged (rounds ran out)"
        return f"{self.rounds} rounds, {state}; scale fixed by {self.scale}; map: {self.map.describe()}"


def joint_names(scene: Scene, names) -> tuple[str, list[str]] | None:
    """``(map name, reflectance names)`` when ``names`` are one environment map's texels
    (``NAME.emission`` of an envmap, (h, w, 3)) plus at least one reflectance path records
    represent (an RGB triple of a material: a reflectance or specular reflectance); else None."""
    maps = [n for n in names if _is_map(scene, n)]
    rest = [n for n in names if n not in maps]
    if len(maps) != 1 or not rest:
        return None
    for n in rest:
        owner = n.rpartition(".")[0]
        if owner not in scene.materials or scene.params[n].ndim != 1 or record_obstacle(scene, [n]) is not None:
            return None
    return maps[0], rest


def _is_map(scene: Scene, name: str) -> bool:
    owner, _, key = name.rpartition(".")
    if key != "emission" or owner not in scene.emitters or scene.params[name].ndim != 3:
        return False
    return bool(getattr(EMITTERS[scene.emitter_spec(scene.emitters.index(owner)).type], "texel_lookup", False))


def scale_anchor(scene: Scene, emitter: str, materials: list[str], views, integrator="path") -> str | None:
    """What fixes the global scale of a joint fit of ``emitter``'s map and ``materials`` (module
    docstring), in a few words, or None when nothing does: a material reflectance not fitted, the
    emission of another emitter, or counted pixels of ``views`` ((view scene, Target) pairs) that
    see the map directly (a render by ``integrator``, a name or a spec, at ``max_depth`` 1 and one
    sample a pixel: an integrator that hides the emitters shows none)."""
    known = [n for n in scene.params if n.rpartition(".")[0] in scene.materials and n not in materials and kind_of(n).polynomial and float(scene.params[n].max()) > 0]
    if known:
        return f"the known reflectance {known[0]}" + (f" (and {len(known) - 1} more)" if len(known) > 1 else "")
    lights = [e for e in scene.emitters if e != emitter and f"{e}.emission" in scene.params and float(scene.params[f"{e}.emission"].max()) > 0]
    if lights:
        return f"the known emission of {lights[0]}"
    seen = 0
    for view_scene, target in views:
        with torch.no_grad():
            direct = render(view_scene, {**({"type": integrator} if isinstance(integrator, str) else integrator), "max_depth": 1}, spp=1, seed=0, progress=False)
        seen += int(((direct.amax(2) > 0) & (target.mask.to(direct.device) > 0)).sum())
    if seen:
        return f"the map seen directly in {seen} counted pixels"
    return None


def fit_joint(
    scene: Scene,
    targets,
    emitter: str = "sky",
    materials=(),
    *,
    cameras=None,
    integrator="path",
    spp: int = 64,
    max_depth: int = 3,
    seed: int = 0,
    mask=None,
    rounds: int = ROUNDS,
    progress: bool = False,
    **map_settings,
) -> JointFit:
    """The map of the envmap ``emitter`` and the reflectances ``materials`` (names such as
    ``"diffuse.reflectance"``, RGB triples) of ``scene`` that reproduce ``targets`` (one image per
    camera of ``cameras``), by alternating the transport-matrix solve of the map with
    Levenberg-Marquardt on path records of the reflectances (module docstring), from the scene's
    current values, for at most ``rounds`` rounds.

    ``spp``: samples per pixel of each half of the transport matrix and of each record set;
    ``max_depth``: Neumann terms (Mitsuba's count); ``map_settings``: :func:`fit_map`'s solve
    settings (``smoothness``, ``tikhonov``, ``rule``, ``weight``, ``target_noise``, ``unknowns``).
    Refused in one line when nothing fixes the global scale (:func:`scale_anchor`)."""
    from invrender.inverse.least_squares import solve  # JAX: imported on first use

    envmap_of(scene, emitter)
    names = check_names(scene.params, list(materials) if not isinstance(materials, str) else [m.strip() for m in materials.split(",") if m.strip()])
    map_name = f"{emitter}.emission"
    if not names or joint_names(scene, [map_name, *names]) is None:
        raise ParameterError(f"fit_joint fits an envmap's texels with material reflectances (RGB triples path records represent), got materials {names!r}")
    if isinstance(rounds, bool) or not isinstance(rounds, int) or rounds < 1:
        raise ParameterError(f"fit_joint rounds must be an integer >= 1, got {rounds!r}")
    if isinstance(max_depth, bool) or not isinstance(max_depth, int) or max_depth < 1:
        raise ParameterError(f"fit_joint needs a finite max_depth >= 1 (records' polynomial degree), got {max_depth!r}")
    views = load_targets(scene, targets, cameras, mask=mask)
    spec = {"type": integrator, "max_depth": max_depth} if isinstance(integrator, str) else {**integrator, "max_depth": max_depth}
    anchor = scale_anchor(scene, emitter, names, views, spec)
    if anchor is None:
        raise ParameterError(
            f"fit_joint: nothing fixes the scale between {map_name} and {', '.join(names)} (the images determine their product, not the split): "
            "keep one reflectance known (leave it out of materials), give another light, or unmask pixels that see the map directly"
        )
    linear = [t.linear for _, t in views]
    masks = None if all(t.plain for _, t in views) else [t.mask for _, t in views]
    options = {k: v for k, v in spec.items() if k not in ("type", "max_depth")}
    x = torch.cat([scene.params[n].detach().double().clamp(1e-4, 1 - 1e-4) for n in names])  # the reflectances, flat (3 k,)
    history, seconds = [], {"map": 0.0, "records": 0.0, "solve": 0.0}
    converged, found, values, std_error = False, None, {}, {}
    steps = _Anderson()
    for rnd in range(rounds):
        at = {n: x[3 * i : 3 * i + 3] for i, n in enumerate(names)}
        clock = time.perf_counter()
        # (a) the map given the reflectances; the scene's starting map keeps the sampling fixed
        found = fit_map(scene.with_params({n: v.float() for n, v in at.items()}, detach=True), linear, emitter, cameras=cameras, integrator=spec,
                        spp=spp, max_depth=None, seed=seed, mask=masks, rounds=1, progress=False, **map_settings)  # fmt: skip
        seconds["map"] += time.perf_counter() - clock
        # (b) the reflectances given the map: two independent record sets per view, common seeds every round
        clock = time.perf_counter()
        texels = found.texels.clamp_min(0.0)
        sets = ([], [])
        for v, (view_scene, _) in enumerate(views):
            here = view_scene.with_params({map_name: texels, **{n: x.float() for n, x in at.items()}}, detach=True)
            for half in (0, 1):
                sets[half].append(record_paths(here, names, spp=spp, max_depth=max_depth, seed=seed * 1_000_003 + 2 * v + half, integrator=spec["type"], progress=False, **options))
        seconds["records"] += time.perf_counter() - clock
        clock = time.perf_counter()
        sol = solve(sets[0], sets[1], [t for _, t in views], at, solver="lm")
        seconds["solve"] += time.perf_counter() - clock
        values, std_error = {n: sol.values[n].double() for n in names}, sol.std_error
        g = torch.cat([values[n] for n in names])  # G(x): one alternation from x
        se = torch.cat([std_error[n] for n in names]).clamp_min(1e-12)
        moved = float(((g - x).abs() / se).max())  # the fixed point's residual, in standard errors
        history.append({"round": rnd + 1, "values": {n: values[n].tolist() for n in names}, "loss": sol.loss, "moved": moved, "seconds": sum(seconds.values())})
        if progress:
            print(f"fit_joint: round {rnd + 1}: moved {moved:.2g} standard errors; " + "; ".join(f"{n} {_rgb(values[n])}" for n in names), flush=True)
        if rnd >= 1 and moved < MOVE:
            converged = True
            break
        x = steps.next(x, g).clamp(1e-4, 1 - 1e-4)
    return JointFit(
        texels=found.texels, values={n: v.float() for n, v in values.items()}, std_error={n: s.float() for n, s in std_error.items()}, map=found,
        scale=anchor, rounds=len(history), converged=converged, history=history, seconds=seconds,
    )  # fmt: skip


def _rgb(v: torch.Tensor) -> str:
    return "(" + ", ".join(f"{float(x):.4f}" for x in v) + ")"



class _Anderson:
    """Anderson acceleration of the fixed-point iteration ``x <- G(x)`` (one alternation round is
    G): the next point is ``G(x_k) - dG gamma`` with ``gamma`` the least-squares coefficients that
    make the residuals' combination ``f_k - dF gamma`` (``f = G(x) - x``) smallest over the last
    :attr:`depth` differences. The plain alternation contracts slowly where the map and the
    reflectances trade off (a factor 0.7 a round measured on sky_spheres); on a problem of a few
    unknowns this is a secant method that takes it in a few rounds."""

    depth = 4

    def __init__(self):
        self.xs, self.gs = [], []

    def next(self, x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        self.xs, self.gs = (self.xs + [x])[-self.depth - 1 :], (self.gs + [g])[-self.depth - 1 :]
        if len(self.xs) < 2:
            return g
        F = torch.stack([b - a for a, b in zip(self.xs, self.gs)], 1)  # (n, m + 1) residuals
        G = torch.stack(self.gs, 1)
        dF, dG = F[:, 1:] - F[:, :-1], G[:, 1:] - G[:, :-1]
        gamma = torch.linalg.lstsq(dF, F[:, -1:], rcond=1e-10).solution
        return g - (dG @ gamma)[:, 0]
