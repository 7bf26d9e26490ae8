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

    [photograph]                       # optional: the targets as a camera would store them
    exposure = 0.6                     # one number, or one per view
    white_balance = [0.8, 1.0, 1.25]   # RGB gains, or one per view (normalized to green = 1)
    response = "srgb"                  # the camera's response (docs/photographs.md)
    format = "jpg"                     # jpg (8 bits) or png (bits = 8 or 16)
    quality = 95                       # JPEG quality (chroma not subsampled)

``invrender dataset RECIPE --out DIR`` writes ``view_NN.exr`` (linear) and ``view_NN.png`` (preview),
``truth.json`` (every parameter's true value) and ``manifest.json`` (scene, settings, views); with
``[photograph]``, ``view_NN.jpg`` (or ``.png``) is each view's target instead, made by
:func:`invrender.inverse.sensor.photograph` (exposure, white balance, clipping, response,
quantization), ``view_NN.exr`` its linear radiance, and the truth holds ``sensor.exposure`` (V,) and
``sensor.white_balance`` (V, 3).

Fit recipe::

    dataset = "../datasets_synthetic/cornell_random.toml"   # required: a dataset recipe (generated on demand)
    params = ["red.reflectance", "light.emission"]          # required

    [init]                             # starting values: a parameter name, or a kind ("reflectance",
                                       # "specular_reflectance", "emission")
    reflectance = 0.5                  # for every fitted parameter of that kind
    emission = 5.0

    [fit]                              # any FitSettings field (invrender.inverse.fit)
    steps = 200
    integrator = { type = "path", rr_depth = 3 }   # an integrator spec: a name or a table

    [photo]                            # optional: the targets as photographs (docs/photographs.md)
    mask = "mask.png"                  # pixel weights (relative to the recipe), or one per view
    response = "linear"                # the targets' response (the dataset's EXRs: linear)
    sensor = { shared = ["exposure"] } # sensor options: exposure, white_balance, shared
    exclude_clipped = true

    [[variants]]                       # optional: one fit per variant, on the same targets, and a
    label = "utah + eps0"              # table of every variant's parameter errors (a model study);
    integrator = "utah"                # required label; any [fit] setting overrides [fit];
    params = ["ambient.emission"]      # fitted in addition to the recipe's params
    init = { "ambient.emission" = 0.05 }   # starting values in addition to [init]
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import torch

from invrender.errors import InvRenderError, ParameterError, SceneError
from invrender.scene import load_scene
from invrender.scene.camera import Camera
from invrender.scene.kinds import KINDS as PARAM_KINDS
from invrender.scene.kinds import kind_of
from invrender.scene.formats.toml import camera_from_table, check_keys, integer, read_toml, table, vector
from invrender.scene.scene import AMBIENT, Scene, check_param_value, unknown_parameter

DATASET_KEYS = {"scene", "resolution", "spp", "max_depth", "seed", "randomize", "set", "views", "photograph"}
PHOTOGRAPH_KEYS = {"exposure", "white_balance", "response", "format", "bits", "quality"}
FIT_KEYS = {"dataset", "params", "init", "fit", "photo", "variants"}
PHOTO_KEYS = {"mask", "response", "sensor", "exclude_clipped"}
VARIANT_KEYS = {"label", "params", "init"}
KINDS = tuple(PARAM_KINDS)  # [init] keys that start every fitted parameter of that kind


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
    photograph: dict | None = None  # the [photograph] table, checked (see make_dataset)


@dataclass(frozen=True)
class FitChoices:
    """What one fit fits and how, as a fit recipe and each of its variants give it.

    Attributes:
        params: names of the fitted parameters (a variant's: in addition to the recipe's).
        init: starting values, as :func:`apply_init` takes them (a variant's: over the recipe's).
        settings: :class:`~invrender.inverse.fit.FitSettings` fields (a variant's: over the recipe's).
    """

    params: list[str]
    init: dict[str, object]
    settings: dict


@dataclass(frozen=True)
class FitVariant(FitChoices):
    """One fit of a model study: a label and the choices it adds to the recipe's."""

    label: str

    @property
    def slug(self) -> str:
        """The label as a folder name."""
        return re.sub(r"[^A-Za-z0-9.-]+", "_", self.label).strip("_") or "variant"


@dataclass(frozen=True)
class FitRecipe(FitChoices):
    """A parsed fit recipe (see the module docstring)."""

    path: Path
    dataset: DatasetRecipe
    variants: list[FitVariant] = dataclasses.field(default_factory=list)
    photo: dict = dataclasses.field(default_factory=dict)  # fit's mask, response, sensor, exclude_clipped


def _recipe_errors(parse):
    """Recipes are checked with the scene format's helpers, which raise SceneError; a bad recipe
    is a ParameterError (same message, naming the file and key)."""

    @functools.wraps(parse)
    def checked(path):
        try:
            return parse(path)
        except SceneError as e:
            raise ParameterError(str(e)) from None

    return checked


def _read_recipe(path, keys: set, required: str, what: str) -> tuple[Path, str, dict]:
    """(path, its name for messages, the document) of a recipe whose keys must be among ``keys`` and
    whose string key ``required`` (``what``) must be there."""
    path = Path(path)
    doc = read_toml(path, "recipe")
    check_keys(doc, keys, str(path))
    if not isinstance(doc.get(required), str):
        raise ParameterError(f"{path}: '{required}' ({what}) is required")
    return path, str(path), doc


@_recipe_errors
def load_dataset_recipe(path) -> DatasetRecipe:
    """A dataset recipe (format in the module docstring); ParameterError naming the file and key."""
    path, where, doc = _read_recipe(path, DATASET_KEYS, "scene", "a built-in name or a scene file")
    scene = doc["scene"]
    if Path(scene).suffix:  # a file, relative to the recipe
        scene = str((path.parent / scene).resolve())
    width, height = vector(doc, "resolution", where, length=2) if "resolution" in doc else (64, 64)
    if not all(r > 0 and r == int(r) for r in (width, height)):
        raise ParameterError(f"{where}: 'resolution' must be [width, height], positive integers")
    bounds = table(doc, "randomize", where)
    randomize = {name: tuple(vector(bounds, name, f"{where} [randomize]", length=2)) for name in bounds}
    for name, (low, high) in randomize.items():
        if low > high:
            raise ParameterError(f"{where} [randomize]: '{name}' must be [low, high], low <= high")
    views = doc.get("views", [])
    if not isinstance(views, list):
        raise ParameterError(f"{where}: 'views' must be an array of tables ([[views]])")
    cameras = [camera_from_table(v, f"{where} views[{i}]") for i, v in enumerate(views)]
    spp = integer(doc, "spp", where) if "spp" in doc else 1024
    if spp <= 0:
        raise ParameterError(f"{where}: 'spp' must be positive")
    max_depth = integer(doc, "max_depth", where) if "max_depth" in doc else 8
    seed = integer(doc, "seed", where) if "seed" in doc else 0
    photograph = _photograph(doc["photograph"], f"{where} [photograph]", max(len(cameras), 1)) if "photograph" in doc else None
    return DatasetRecipe(path, scene, (int(width), int(height)), spp, max_depth, seed, randomize, dict(table(doc, "set", where)), cameras, photograph)


def _photograph(doc, where: str, views: int) -> dict:
    """A dataset recipe's ``[photograph]`` table, checked: exposure (V,) and white balance (V, 3)
    per view (green = 1: a white balance's green gain is moved into the exposure), response,
    suffix, bits, quality."""
    from invrender.io.response import response as make_response

    if not isinstance(doc, dict):
        raise ParameterError(f"{where}: must be a table")
    check_keys(doc, PHOTOGRAPH_KEYS, where)
    exposure = doc.get("exposure", 1.0)
    exposure = [exposure] * views if isinstance(exposure, (int, float)) and not isinstance(exposure, bool) else exposure
    wb = doc.get("white_balance", [1.0, 1.0, 1.0])
    wb = [wb] * views if isinstance(wb, list) and len(wb) == 3 and all(isinstance(x, (int, float)) for x in wb) else wb
    number = lambda x: isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0  # noqa: E731
    if not (isinstance(exposure, list) and len(exposure) == views and all(number(x) for x in exposure)):
        raise ParameterError(f"{where}: 'exposure' must be a positive number or one per view ({views})")
    if not (isinstance(wb, list) and len(wb) == views and all(isinstance(g, list) and len(g) == 3 and all(number(x) for x in g) for g in wb)):
        raise ParameterError(f"{where}: 'white_balance' must be positive [r, g, b] gains or one per view ({views})")
    response = doc.get("response", "srgb")
    try:
        make_response(response)
    except InvRenderError as e:
        raise ParameterError(f"{where}: {e}") from None
    suffix = doc.get("format", "jpg")
    bits = doc.get("bits", 8)
    if suffix not in ("jpg", "png") or bits not in (8, 16) or (suffix == "jpg" and bits != 8):
        raise ParameterError(f"{where}: 'format' must be \"jpg\" (8 bits) or \"png\" ('bits' 8 or 16), got {suffix!r} with {bits!r} bits")
    quality = doc.get("quality", 95)
    if isinstance(quality, bool) or not isinstance(quality, int) or not 1 <= quality <= 100:
        raise ParameterError(f"{where}: 'quality' must be an integer in [1, 100], got {quality!r}")
    return {
        "exposure": [float(e) * float(g[1]) for e, g in zip(exposure, wb)],
        "white_balance": [[float(g[0]) / float(g[1]), 1.0, float(g[2]) / float(g[1])] for g in wb],
        "response": response, "suffix": "." + suffix, "bits": int(bits), "quality": int(quality),
    }  # fmt: skip


def dataset_scene(recipe: DatasetRecipe) -> Scene:
    """The recipe's scene at its resolution, with its true (randomized and set) parameters."""
    scene = load_scene(recipe.scene, resolution=recipe.resolution)
    names = set(recipe.randomize) | set(recipe.fixed)
    unknown = sorted(names - set(scene.params))
    if unknown:
        raise unknown_parameter(unknown[0], scene.params, f"{recipe.path}: unknown parameter")
    generator = torch.Generator().manual_seed(recipe.seed)
    with torch.no_grad():
        for name, (low, high) in recipe.randomize.items():
            p = scene.params[name]
            p.copy_(low + (high - low) * torch.rand(p.shape, generator=generator))
            check_param_value(name, p)
    for name, value in recipe.fixed.items():
        set_param(scene, name, value)
    return scene


def set_param(scene: Scene, name: str, value) -> None:
    """Set ``scene.params[name]`` in place to a checked ``value`` (a number, an RGB triple, or a
    texture of the parameter's own shape); ParameterError naming it otherwise."""
    param = scene.params[name]
    t = check_param_value(name, value)
    if t.shape != param.shape and t.shape != (3,):
        raise ParameterError(f"{name}: a value of shape {tuple(t.shape)} does not fit the parameter's shape {tuple(param.shape)}")
    with torch.no_grad():
        param.copy_(t.expand_as(param))


def make_dataset(recipe, out, progress: bool = True) -> dict:
    """Render a dataset recipe (a :class:`DatasetRecipe` or its path) into ``out``; returns the manifest."""
    from invrender.io.reports import write_json
    from invrender.io import write_image
    from invrender.estimators import render

    recipe = recipe if isinstance(recipe, DatasetRecipe) else load_dataset_recipe(recipe)
    scene = dataset_scene(recipe)
    out = Path(out)
    cameras = recipe.views or [scene.camera]
    photo = recipe.photograph
    views = []
    for i, camera in enumerate(cameras):
        image = render(scene.with_camera(camera), spp=recipe.spp, max_depth=recipe.max_depth, seed=recipe.seed + 7919 * (i + 1), progress=progress)
        write_image(out / f"view_{i:02d}.exr", image)
        if photo is None:
            write_image(out / f"view_{i:02d}.png", image)
            views.append({"image": f"view_{i:02d}.exr", "camera": dataclasses.asdict(camera)})
            continue
        from invrender.io.images import write_photo
        from invrender.inverse.sensor import photograph

        name = f"view_{i:02d}{photo['suffix']}"
        encoded = photograph(image, photo["exposure"][i], photo["white_balance"][i], photo["response"])
        write_photo(out / name, encoded, bits=photo["bits"], quality=photo["quality"])
        views.append({"image": name, "radiance": f"view_{i:02d}.exr", "camera": dataclasses.asdict(camera)})
    truth = {k: v.tolist() for k, v in scene.params.items()}
    if photo is not None:
        truth |= {"sensor.exposure": photo["exposure"][: len(cameras)], "sensor.white_balance": photo["white_balance"][: len(cameras)]}
    write_json(out / "truth.json", truth)
    manifest = {
        "recipe": str(recipe.path),
        "scene": recipe.scene,
        "resolution": list(recipe.resolution),
        "spp": recipe.spp,
        "max_depth": recipe.max_depth,
        "seed": recipe.seed,
        "randomized": sorted(recipe.randomize),
        "views": views,
        **({"photograph": {k: v for k, v in photo.items()}} if photo is not None else {}),
    }
    write_json(out / "manifest.json", manifest)
    return manifest


def load_dataset(directory) -> tuple[Scene, list, list[Camera], dict[str, torch.Tensor]]:
    """(scene at the dataset's resolution, targets, cameras, truth) of a generated dataset; the
    targets are (H, W, 3) linear tensors, or the paths of photographs (``[photograph]``), which a
    fit reads with their bit depth and response."""
    from invrender.io import read_image

    directory = Path(directory)
    try:
        manifest = json.loads((directory / "manifest.json").read_text())
        truth = json.loads((directory / "truth.json").read_text())
    except FileNotFoundError as e:
        raise ParameterError(f"not a dataset folder (no {Path(e.filename).name}): {directory}") from None
    except (OSError, ValueError) as e:
        raise ParameterError(f"cannot read dataset {directory}: {e}") from None
    try:
        scene_name, resolution, views = manifest["scene"], tuple(manifest["resolution"]), manifest["views"]
        images, cameras = [directory / v["image"] for v in views], [Camera(**v["camera"]) for v in views]
    except (KeyError, TypeError) as e:
        raise ParameterError(f"{directory / 'manifest.json'} is not an invrender dataset manifest ({type(e).__name__}: {e})") from None
    scene = load_scene(scene_name, resolution=resolution)
    targets = [read_image(p) if p.suffix.lower() == ".exr" else str(p) for p in images]
    return scene, targets, cameras, {k: torch.tensor(v) for k, v in truth.items()}


@_recipe_errors
def load_fit_recipe(path) -> FitRecipe:
    """A fit recipe and the dataset recipe it names (format in the module docstring); ParameterError
    naming the file and key."""
    path, where, doc = _read_recipe(path, FIT_KEYS, "dataset", "a dataset recipe")
    settings = table(doc, "fit", where)
    check_keys(settings, _setting_names(), f"{where} [fit]")
    choices = _fit_choices(doc, settings, where, required=True)
    dataset = load_dataset_recipe(path.parent / doc["dataset"])
    variants = doc.get("variants", [])
    if not isinstance(variants, list):
        raise ParameterError(f"{where}: 'variants' must be an array of tables ([[variants]])")
    variants = [_variant(v, f"{where} variants[{i}]") for i, v in enumerate(variants)]
    if len({v.slug for v in variants}) != len(variants):
        raise ParameterError(f"{where}: variant labels must differ")
    for label, own in [("[fit]", {})] + [(f"variant {v.label!r}", v.settings) for v in variants]:
        _check_settings({**choices["settings"], **own}, f"{where} {label}")  # before any work
    return FitRecipe(**choices, path=path, dataset=dataset, variants=variants, photo=_photo(doc, path, where))


def check_fit_recipe(recipe: FitRecipe, init: dict | None = None, settings: dict | None = None) -> None:
    """Everything the fits of ``recipe`` will check that is known before its dataset is rendered:
    each fit's settings (``settings`` over the recipe's ``[fit]``, a variant's over both), the
    dataset's ``[randomize]`` and ``[set]`` names and values, each fit's parameter names and
    starting values (``init`` over the recipe's ``[init]``, a variant's over both), and the
    ``[photo]`` table (sensor options, responses, masks: readable, of the dataset's size). A
    one-line :class:`ParameterError` (or the :class:`ImageError` of a mask) naming the recipe, so
    that a bad recipe leaves nothing behind in the output folder."""
    from invrender.inverse.fit import FitSettings, check_fit_names
    from invrender.inverse.sensor import Sensor
    from invrender.inverse.targets import make_targets

    where = str(recipe.path)

    def named(what: str, check):
        try:
            return check()
        except InvRenderError as e:
            raise type(e)(f"{where}{what}: {e}") from None

    fits = [(None, recipe.params, {}, {})] + [(v, recipe.params + [p for p in v.params if p not in recipe.params], v.init, v.settings) for v in recipe.variants]
    for variant, _, _, own in fits:
        label = f" variant {variant.label!r}" if variant is not None else " [fit]"
        named(label, lambda: FitSettings(**{**recipe.settings, **(settings or {}), **own}))
    scene = named(f" (its dataset {recipe.dataset.path})", lambda: dataset_scene(recipe.dataset))
    views = max(len(recipe.dataset.views), 1)
    photo = recipe.photo
    for variant, names, own_init, _ in fits:
        label = f" variant {variant.label!r}" if variant is not None else ""
        started = scene.with_params(detach=True)  # an [init] may add the ambient eps0 a variant fits
        known = [n for n in names if n in scene.params]
        start, sensor = split_init({**recipe.init, **(init or {}), **own_init}, photo.get("sensor"))
        named(f"{label} [init]", lambda: apply_init(started, known, start))
        named(f"{label} params", lambda: check_fit_names(started, names))
        named(" [photo] sensor", lambda: Sensor.make(views, names, sensor))
    # the targets will be the dataset's views: the masks and responses checked against stand-ins
    # of the dataset's size, as the fit checks them against the files
    width, height = recipe.dataset.resolution
    grey = [torch.full((height, width, 3), 0.5)] * views
    labels = [f"view {i} of the dataset" for i in range(views)]
    named(" [photo]", lambda: make_targets(grey, labels, [(width, height)] * views, photo.get("mask"), photo.get("response"), exclude=False))


def _photo(doc: dict, path: Path, where: str) -> dict:
    """A fit recipe's ``[photo]`` table as fit's keyword arguments (mask paths relative to the
    recipe), checked for its keys and types."""
    photo = dict(table(doc, "photo", where))
    check_keys(photo, PHOTO_KEYS, f"{where} [photo]")
    if "mask" in photo:
        masks = photo["mask"] if isinstance(photo["mask"], list) else [photo["mask"]]
        if not all(isinstance(m, str) for m in masks):
            raise ParameterError(f"{where} [photo]: mask must be a path or a list of paths")
        resolved = [str(path.parent / m) for m in masks]
        photo["mask"] = resolved if isinstance(photo["mask"], list) else resolved[0]
    if "sensor" in photo and not isinstance(photo["sensor"], dict):
        raise ParameterError(f"{where} [photo]: sensor must be a table (exposure, white_balance, shared)")
    if "exclude_clipped" in photo and not isinstance(photo["exclude_clipped"], bool):
        raise ParameterError(f"{where} [photo]: exclude_clipped must be true or false")
    return photo


def _variant(doc, where: str) -> FitVariant:
    if not isinstance(doc, dict):
        raise ParameterError(f"{where}: a variant must be a table ([[variants]])")
    check_keys(doc, VARIANT_KEYS | _setting_names(), where)
    if not isinstance(doc.get("label"), str) or not doc["label"]:
        raise ParameterError(f"{where}: 'label' (a name for the table) is required")
    settings = {k: v for k, v in doc.items() if k not in VARIANT_KEYS}
    return FitVariant(**_fit_choices(doc, settings, where, required=False), label=doc["label"])


def _fit_choices(doc: dict, settings: dict, where: str, required: bool) -> dict:
    """The :class:`FitChoices` fields of a recipe or variant table ``doc``, checked; ``required``:
    ``params`` must name at least one parameter."""
    params = doc.get("params", [])
    if not (isinstance(params, list) and all(isinstance(p, str) for p in params)) or (required and not params):
        raise ParameterError(f"{where}: 'params' must be a {'non-empty ' if required else ''}list of parameter names")
    return {"params": list(params), "init": dict(table(doc, "init", where)), "settings": dict(settings)}


def _check_settings(settings: dict, where: str) -> None:
    """The fit settings of a recipe (or of one of its variants) checked as a fit checks them,
    the integrator spec included; a one-line error naming ``where``."""
    from invrender.inverse.fit import FitSettings

    try:
        FitSettings(**settings)
    except ParameterError as e:
        raise ParameterError(f"{where}: {e}") from None


def _setting_names() -> set[str]:
    from invrender.inverse.fit import FitSettings  # lazily: the fitting machinery is not needed to read a recipe

    return {f.name for f in dataclasses.fields(FitSettings)}


def split_init(init: dict, sensor: dict | None = None) -> tuple[dict, dict]:
    """``(the scene's starting values, the fit's sensor options)`` of ``init``: a sensor
    parameter's value (``sensor.exposure``, ``sensor.white_balance``: every name a fit's params
    accept) is not a scene parameter but the sensor option of that name, its starting value
    (the fixed value when it is not fitted), merged over ``sensor``."""
    from invrender.inverse.sensor import NAMES as SENSOR_NAMES  # lazily: reading a recipe needs no fitting machinery

    scene = {k: v for k, v in init.items() if k not in SENSOR_NAMES}
    options = {**(sensor or {}), **{k.partition(".")[2]: v for k, v in init.items() if k in SENSOR_NAMES}}
    return scene, options


def apply_init(scene: Scene, names: list[str], init: dict) -> None:
    """Set starting values in place: keys are parameter names, or a kind (``reflectance``,
    ``specular_reflectance``, ``emission``) for every fitted parameter of that kind (but not the ambient eps0); a parameter's own value
    wins over its kind's. An ``ambient.emission`` value starts eps0 in a scene that had none."""
    values = {}
    for kind in KINDS:
        if kind in init:
            values.update({name: init[kind] for name in names if kind_of(name).key == kind and name != AMBIENT})
    values.update({name: value for name, value in init.items() if name not in KINDS})
    for name, value in values.items():
        if name == AMBIENT and name not in scene.params:
            scene.params[AMBIENT] = scene.with_ambient(value).params[AMBIENT]  # checked as eps0 is
        elif name not in scene.params:
            raise unknown_parameter(name, scene.params, "initial value for unknown parameter")
        else:
            set_param(scene, name, value)
