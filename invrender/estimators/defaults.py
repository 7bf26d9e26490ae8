"""The render settings a scene file states (``scene.defaults``) as the defaults of renders and fits.

A Mitsuba XML file states its integrator (``<integrator type="path">`` with ``max_depth``,
``rr_depth``, ...) and its sample count (``<sampler>``'s ``sample_count``); the film's size is
the scene's resolution already. ``scene.defaults`` holds what the file states:
``{"integrator": "path", "max_depth": 6, "spp": 16}`` (only the keys the file gives; empty for
built-in scenes and the other formats).

The rule (docs/rendering.md, "The scene file's settings"):

- No integrator given: the file's integrator with the file's settings (``"path"`` when the file
  names none).
- An integrator given by name or ``{"type": ...}`` mapping: when it is the file's integrator, the
  file's settings fill in those not given; another integrator starts from its own defaults (the
  file's settings belong to the file's integrator).
- Settings given (beside the name, in the mapping, or as keywords) win; each one that differs
  from the file's value, and another integrator than the file's, is reported as overridden (one
  warning a call: :func:`report`). Nothing is reported when nothing conflicts.
- An :class:`~invrender.plugins.integrators.Integrator` object is used as it is: the file's
  integrator is not consulted (it is a complete choice of every setting).
- ``spp`` not given: the file's sample count, else :data:`DEFAULT_SPP`. A different ``spp``
  changes the noise only, not the image's expected value, and is not warned about
  (``invrender render`` says it in its summary line).
"""

from __future__ import annotations

import warnings

from invrender import registry
from invrender.scene.scene import Scene
from invrender.plugins.integrators import Integrator

#: samples per pixel when neither the caller nor the scene file gives any
DEFAULT_SPP = 64
#: the integrator when neither the caller nor the scene file names one
DEFAULT_INTEGRATOR = "path"


def file_integrator(scene: Scene) -> tuple[str | None, dict]:
    """(name or None, settings) of the integrator the scene file states."""
    defaults = scene.defaults or {}
    return defaults.get("integrator"), {k: v for k, v in defaults.items() if k not in ("integrator", "spp")}


def scene_integrator(scene: Scene, integrator=None, settings: dict | None = None) -> tuple[object, list[str]]:
    """The integrator spec a render of ``scene`` uses, and what in it overrides the file's.

    Args:
        scene: its ``defaults`` are the file's settings.
        integrator: None, a name, a ``{"type": name, ...}`` mapping or an Integrator object.
        settings: settings given beside it (keywords: ``max_depth``, ``rr_depth``, ...); they win
            over the mapping's as in :func:`~invrender.plugins.integrators.make_integrator`.
    Returns:
        (spec, overridden): a ``{"type": name, ...}`` mapping (an Integrator object is returned
        as it is, with ``settings`` left to :func:`make_integrator` to refuse), and one phrase per
        override (``"max_depth=3 overrides the file's max_depth 6"``; empty when nothing conflicts).
    """
    settings = dict(settings or {})
    if isinstance(integrator, Integrator):
        return integrator, []
    file_name, file_settings = file_integrator(scene)
    if integrator is None:
        name, given = file_name or DEFAULT_INTEGRATOR, settings
    else:
        name, spec_settings = registry.integrator_spec(integrator)
        given = {**spec_settings, **settings}
    if file_name is None or name == file_name:
        overridden = [f"{k}={v!r} overrides the file's {k} {file_settings[k]!r}" for k, v in given.items() if k in file_settings and file_settings[k] != v]
        return {"type": name, **file_settings, **given}, overridden
    stated = ", ".join(f"{k} {v!r}" for k, v in file_settings.items())
    return {"type": name, **given}, [f"integrator {name!r} replaces the file's {file_name!r}" + (f" and its settings ({stated})" if stated else "")]


def fit_settings(scene: Scene, settings: dict) -> dict:
    """A fit's settings (:class:`~invrender.inverse.fit.FitSettings` keywords) with the scene
    file's integrator as the default of ``integrator`` (as :func:`scene_integrator` combines
    them), reporting overrides. A ``max_depth`` setting given wins over the file's ``max_depth``
    (not over one in the ``integrator`` given: FitSettings refuses two different depths). The
    file's sample count is not used: a fit's spp schedule is its own."""
    file_name, file_settings = file_integrator(scene)
    integrator = settings.get("integrator")
    if (file_name is None and not file_settings) or isinstance(integrator, Integrator):
        return settings
    given = registry.integrator_spec(integrator)[1] if integrator is not None else {}
    spec, overridden = scene_integrator(scene, integrator)
    depth = settings.get("max_depth")
    if depth is not None and "max_depth" in spec and "max_depth" not in given:
        if spec.pop("max_depth") != depth:
            overridden.append(f"max_depth={depth!r} overrides the file's max_depth {file_settings['max_depth']!r}")
    report(scene, overridden, stacklevel=4)
    return {**settings, "integrator": spec}


def scene_spp(scene: Scene, spp: int | None) -> int:
    """``spp`` when given, else the file's sample count, else :data:`DEFAULT_SPP`."""
    return spp if spp is not None else (scene.defaults or {}).get("spp", DEFAULT_SPP)


def report(scene: Scene, overridden: list[str], stacklevel: int = 3) -> None:
    """One warning naming the scene and every setting given that overrides its file's (none when
    ``overridden`` is empty)."""
    if overridden:
        warnings.warn(f"scene {scene.name!r}: {'; '.join(overridden)}", SettingOverridden, stacklevel=stacklevel)


class SettingOverridden(UserWarning):
    """A render or fit setting given explicitly differs from the one the scene file states."""


__all__ = ["DEFAULT_INTEGRATOR", "DEFAULT_SPP", "SettingOverridden", "file_integrator", "fit_settings", "report", "scene_integrator", "scene_spp"]
