"""Declarative recipes: synthetic datasets (``datasets_synthetic/*.toml``) and fits (``optimize/*.toml``).

Dataset recipe::

    scene = "cornell_box"              # required: a built-in name or a scene file (relative to the recipe)
    resolution = [64, 64]              # width, height
    spp = 1024                         # samples per pixel of the target renders
    max_depth = 8
    seed = 0                           # draws the random parameters and seeds the renders

    [randomize]                        # parameter -> [low, high]: every channel (and texel) uniform
    "red.reflectance" = [0.05, 0.95]

    [set]                              # parameter -> fixed value (a number, RGB)
    "light.emission" = [12, 10, 8]

    [[views]]                          # cameras, each as the scene format's [camera]; default: the scene's
    origin = [0, 0, 3.9]

``invrender dataset RECIPE --out DIR`` writes ``view_NN.exr`` (linear) and ``view_NN.png`` (preview),
``truth.json`` (every parameter's true value) and ``manifest.json`` (scene, settings, views).

Fit recipe::

    dataset = "../datasets_synthetic/cornell_random.toml"   # required: a dataset recipe (generated on demand)
    params = ["red.reflectance", "light.emission"]          # required

    [init]                             # starting values: a parameter name, or "reflectance" / "emission"
    reflectance = 0.5                  # for every fitted parameter of that kind
    emission = 5.0

    [fit]                              # any FitSettings field (invrender.inverse.fit)
    steps = 200

    [[variants]]                       # optional: one fit per variant, on the same targets, and a
    label = "utah + eps0"              # table of every variant's parameter errors (a model study);
    integrator = "utah"                # required label; any [fit] setting overrides [fit];
    params = ["ambient.emission"]      # fitted in addition to the recipe's params
    init = { "ambient.emission" = 0.05 }   # starting values in addition to [init]
"""

from __future__ import annotations

import dataclasses
import json
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

import torch

from invrender.errors import InvRenderError, ParameterError, SceneError
from invrender.scene import load_scene
from invrender.scene.camera import Camera
from invrender.scene.scene import AMBIENT, Scene, check_param_value

DATASET_KEYS = {"scene", "resolution", "spp", "max_depth", "seed", "randomize", "set", "views"}
FIT_KEYS = {"dataset", "params", "init", "fit", "variants"}
VARIANT_KEYS = {"label", "params", "init"}
CAMERA_KEYS = {"origin", "target", "up", "fov", "fov_axis"}


@dataclass(frozen=True)
class DatasetRecipe:
    """A parsed dataset recipe (see the module docstring)."""

    path: Path
    scene: str
    resolution: tuple[int, int]
    spp: int
    max_depth: int
    seed: int
    randomize: dict[str, tuple[float, float]]
    fixed: dict[str, object]
    views: list[Camera]


@dataclass(frozen=True)
class FitRecipe:
    """A parsed fit recipe (see the module docstring)."""

    path: Path
    dataset: DatasetRecipe
    params: list[str]
    init: dict[str, object]
    settings: dict
    variants: list["FitVariant"] = dataclasses.field(default_factory=list)


@dataclass(frozen=True)
class FitVariant:
    """One fit of a model study: a label, settings overriding the recipe's, extra parameters."""

    label: str
    settings: dict
    params: list[str]
    init: dict[str, object]

    @property
    def slug(self) -> str:
        """The label as a folder name."""
        return re.sub(r"[^A-Za-z0-9.-]+", "_", self.label).strip("_") or "variant"


def _read_toml(path) -> dict:
    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ParameterError(f"recipe not found: {path}") from None
    except OSError as e:
        raise ParameterError(f"cannot read recipe {path}: {e.strerror or e}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ParameterError(f"{path}: invalid TOML: {e}") from None


def _check_keys(doc: dict, allowed: set, where: str) -> None:
    unknown = sorted(set(doc) - allowed)
    if unknown:
        raise ParameterError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(sorted(allowed))})")


def _int(doc, key, default, where) -> int:
    value = doc.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ParameterError(f"{where}: '{key}' must be an integer, got {value!r}")
    return value


def load_dataset_recipe(path) -> DatasetRecipe:
    path = Path(path)
    doc = _read_toml(path)
    where = str(path)
    _check_keys(doc, DATASET_KEYS, where)
    if not isinstance(doc.get("scene"), str):
        raise ParameterError(f"{where}: 'scene' (a built-in name or a scene file) is required")
    scene = doc["scene"]
    if Path(scene).suffix:  # a file, relative to the recipe
        scene = str((path.parent / scene).resolve())
    resolution = doc.get("resolution", [64, 64])
    if not (isinstance(resolution, list) and len(resolution) == 2 and all(isinstance(r, int) and r > 0 for r in resolution)):
        raise ParameterError(f"{where}: 'resolution' must be [width, height], positive integers")
    randomize = {}
    for name, bounds in doc.get("randomize", {}).items():
        if not (isinstance(bounds, list) and len(bounds) == 2 and all(isinstance(b, (int, float)) for b in bounds) and bounds[0] <= bounds[1]):
            raise ParameterError(f"{where} [randomize]: '{name}' must be [low, high]")
        randomize[name] = (float(bounds[0]), float(bounds[1]))
    views = []
    for i, v in enumerate(doc.get("views", [])):
        if not isinstance(v, dict):
            raise ParameterError(f"{where}: views[{i}] must be a table")
        _check_keys(v, CAMERA_KEYS, f"{where} views[{i}]")
        try:
            views.append(Camera(**v))
        except (TypeError, ValueError) as e:
            raise ParameterError(f"{where} views[{i}]: {e}") from None
    spp, depth = _int(doc, "spp", 1024, where), _int(doc, "max_depth", 8, where)
    if spp <= 0:
        raise ParameterError(f"{where}: 'spp' must be positive")
    return DatasetRecipe(path, scene, tuple(resolution), spp, depth, _int(doc, "seed", 0, where), randomize, dict(doc.get("set", {})), views)


def dataset_scene(recipe: DatasetRecipe) -> Scene:
    """The recipe's scene at its resolution, with its true (randomized and set) parameters."""
    scene = load_scene(recipe.scene, resolution=recipe.resolution)
    names = set(recipe.randomize) | set(recipe.fixed)
    unknown = sorted(names - set(scene.params))
    if unknown:
        raise ParameterError(f"{recipe.path}: unknown parameter {unknown[0]!r} (known: {', '.join(scene.params)})")
    generator = torch.Generator().manual_seed(recipe.seed)
    with torch.no_grad():
        for name, (low, high) in recipe.randomize.items():
            p = scene.params[name]
            p.copy_(low + (high - low) * torch.rand(p.shape, generator=generator))
            check_param_value(name, p)
        for name, value in recipe.fixed.items():
            scene.params[name].copy_(check_param_value(name, value).expand_as(scene.params[name]))
    return scene


def make_dataset(recipe_path, out, progress: bool = True) -> dict:
    """Render a dataset recipe into ``out``; returns the manifest."""
    from invrender.inverse.report import write_json
    from invrender.io import write_image
    from invrender.transport.render import render

    recipe = load_dataset_recipe(recipe_path)
    scene = dataset_scene(recipe)
    out = Path(out)
    cameras = recipe.views or [scene.camera]
    views = []
    for i, camera in enumerate(cameras):
        image = render(scene.with_camera(camera), spp=recipe.spp, max_depth=recipe.max_depth, seed=recipe.seed + 7919 * (i + 1), progress=progress)
        write_image(out / f"view_{i:02d}.exr", image)
        write_image(out / f"view_{i:02d}.png", image)
        views.append({"image": f"view_{i:02d}.exr", "camera": dataclasses.asdict(camera)})
    write_json(out / "truth.json", {k: v.tolist() for k, v in scene.params.items()})
    manifest = {
        "recipe": str(recipe.path),
        "scene": recipe.scene,
        "resolution": list(recipe.resolution),
        "spp": recipe.spp,
        "max_depth": recipe.max_depth,
        "seed": recipe.seed,
        "randomized": sorted(recipe.randomize),
        "views": views,
    }
    write_json(out / "manifest.json", manifest)
    return manifest


def load_dataset(directory) -> tuple[Scene, list[torch.Tensor], list[Camera], dict[str, torch.Tensor]]:
    """(scene at the dataset's resolution, targets, cameras, truth) of a generated dataset."""
    from invrender.io import read_image

    directory = Path(directory)
    try:
        manifest = json.loads((directory / "manifest.json").read_text())
        truth = json.loads((directory / "truth.json").read_text())
    except FileNotFoundError as e:
        raise ParameterError(f"not a dataset folder (no {Path(e.filename).name}): {directory}") from None
    except (OSError, ValueError) as e:
        raise ParameterError(f"cannot read dataset {directory}: {e}") from None
    scene = load_scene(manifest["scene"], resolution=tuple(manifest["resolution"]))
    targets = [read_image(directory / v["image"]) for v in manifest["views"]]
    cameras = [Camera(**v["camera"]) for v in manifest["views"]]
    return scene, targets, cameras, {k: torch.tensor(v) for k, v in truth.items()}


def load_fit_recipe(path) -> FitRecipe:
    path = Path(path)
    doc = _read_toml(path)
    where = str(path)
    _check_keys(doc, FIT_KEYS, where)
    if not isinstance(doc.get("dataset"), str):
        raise ParameterError(f"{where}: 'dataset' (a dataset recipe) is required")
    params = doc.get("params")
    if not (isinstance(params, list) and params and all(isinstance(p, str) for p in params)):
        raise ParameterError(f"{where}: 'params' must be a non-empty list of parameter names")
    dataset = load_dataset_recipe(path.parent / doc["dataset"])
    variants = [_variant(v, f"{where} variants[{i}]") for i, v in enumerate(doc.get("variants", []))]
    if len({v.slug for v in variants}) != len(variants):
        raise ParameterError(f"{where}: variant labels must differ")
    return FitRecipe(path, dataset, params, dict(doc.get("init", {})), dict(doc.get("fit", {})), variants)


def _variant(doc, where: str) -> FitVariant:
    from invrender.inverse.fit import FitSettings

    if not isinstance(doc, dict):
        raise ParameterError(f"{where}: a variant must be a table ([[variants]])")
    _check_keys(doc, VARIANT_KEYS | {f.name for f in dataclasses.fields(FitSettings)}, where)
    if not isinstance(doc.get("label"), str) or not doc["label"]:
        raise ParameterError(f"{where}: 'label' (a name for the table) is required")
    params = doc.get("params", [])
    if not (isinstance(params, list) and all(isinstance(p, str) for p in params)):
        raise ParameterError(f"{where}: 'params' must be a list of parameter names")
    if not isinstance(doc.get("init", {}), dict):
        raise ParameterError(f"{where}: 'init' must be a table of starting values")
    settings = {k: v for k, v in doc.items() if k not in VARIANT_KEYS}
    return FitVariant(doc["label"], settings, list(params), dict(doc.get("init", {})))


def apply_init(scene: Scene, names: list[str], init: dict) -> None:
    """Set starting values in place: keys are parameter names, or ``reflectance`` / ``emission``
    for every fitted parameter of that kind."""
    kinds = [(k, v) for k, v in init.items() if k in ("reflectance", "emission")]
    named = [(k, v) for k, v in init.items() if k not in ("reflectance", "emission")]
    for key, value in kinds + named:  # a parameter's own starting value wins over its kind's
        targets = [n for n in names if n.endswith(f".{key}") and n != AMBIENT] if key in ("reflectance", "emission") else [key]
        for name in targets:
            if name == AMBIENT and name not in scene.params:
                scene.params[AMBIENT] = check_param_value(AMBIENT, value)  # the scene had no eps0: start one
                continue
            if name not in scene.params:
                raise ParameterError(f"initial value for unknown parameter {name!r} (known: {', '.join(scene.params)})")
            try:
                value_t = check_param_value(name, value)
            except InvRenderError:
                raise
            except Exception as e:  # pragma: no cover - defensive
                raise SceneError(f"initial value for {name}: {e}") from None
            with torch.no_grad():
                scene.params[name].copy_(value_t.expand_as(scene.params[name]))
