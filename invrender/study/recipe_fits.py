"""A fit recipe run into an output folder: what ``invrender fit RECIPE`` does, as a library call.

The recipe's dataset is rendered into ``out/dataset`` unless it is there already (in a process
group, rank 0 renders it and the others wait for it), then one fit runs into ``out``
(:func:`~invrender.inverse.fit_output.fit_into`) or, for a recipe with ``[[variants]]`` (a model
study), one fit per variant into ``out/<label>/``, followed by ``out/study.md`` and
``out/study.json``: each parameter channel's relative error under each variant.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from invrender.inverse.fit_output import FitOutput, fit_into
from invrender.inverse.report import study_table
from invrender.io.reports import write_json, write_text
from invrender.recipes import FitRecipe, apply_init, check_fit_recipe, load_dataset, load_fit_recipe, make_dataset, split_init
from invrender.core.ranks import barrier


@dataclass(frozen=True)
class RecipeFits:
    """What :func:`fit_recipe` wrote.

    Attributes:
        fits: label -> its :class:`~invrender.inverse.fit_output.FitOutput` (one entry, label
            ``""``, for a recipe without variants).
        markdown: the study table written to ``study.md`` (None without variants).
        written: the study's own files (``study.md``, ``study.json``).
    """

    fits: dict[str, FitOutput]
    markdown: str | None = None
    written: tuple[Path, ...] = field(default_factory=tuple)


def fit_recipe(
    recipe,
    out,
    *,
    init: dict | None = None,
    settings: dict | None = None,
    resume: bool = False,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    on_fit: Callable[[str, FitOutput], None] | None = None,
) -> RecipeFits:
    """Run the fit recipe ``recipe`` (a path or a :class:`~invrender.recipes.FitRecipe`) into the
    folder ``out`` (module docstring).

    Args:
        init: starting values over the recipe's ``[init]``.
        settings: :class:`~invrender.inverse.fit.FitSettings` fields over the recipe's ``[fit]``
            (a variant's own settings win over both).
        resume: continue each fit from its checkpoint.
        progress: progress bars.
        log: called with a line of news (the dataset being rendered, the variant starting).
        on_fit: called with (label, output) after each fit.
    Returns:
        :class:`RecipeFits`. ``KeyboardInterrupt`` propagates after the running fit's checkpoint is saved.
    """
    recipe = recipe if isinstance(recipe, FitRecipe) else load_fit_recipe(recipe)
    out, log = Path(out), log or (lambda line: None)
    check_fit_recipe(recipe, init, settings)  # every fit's inputs valid before the dataset is written
    data = out / "dataset"
    if not (data / "manifest.json").is_file():
        log(f"rendering the dataset {recipe.dataset.path} into {data}")
        make_dataset(recipe.dataset, data, progress=progress)
    barrier()  # in a process group rank 0 writes the dataset; the others read it
    scene, targets, cameras, truth = load_dataset(data)
    init, sensor = split_init({**recipe.init, **(init or {})}, recipe.photo.get("sensor"))
    settings = {**recipe.settings, **(settings or {})}
    report = {"recipe": str(recipe.path)}
    common = dict(cameras=cameras, truth=truth, resume=resume, progress=progress, **{**recipe.photo, **({"sensor": sensor} if sensor else {})})
    if not recipe.variants:
        apply_init(scene, recipe.params, init)
        output = fit_into(out, scene, targets, recipe.params, report=report, **common, **settings)
        if on_fit:
            on_fit("", output)
        return RecipeFits({"": output})
    fits = {}
    for variant in recipe.variants:
        log(f"variant {variant.label!r}")
        own = scene.with_params(detach=True)
        names = recipe.params + [p for p in variant.params if p not in recipe.params]
        start, own_sensor = split_init({**init, **variant.init}, sensor)
        apply_init(own, names, start)
        output = fit_into(out / variant.slug, own, targets, names, report={**report, "variant": variant.label}, **{**common, **({"sensor": own_sensor} if own_sensor else {})},
                          **{**settings, **variant.settings})
        if on_fit:
            on_fit(variant.label, output)
        fits[variant.label] = output
    markdown, table = study_table({label: o.result for label, o in fits.items()}, truth)
    write_text(out / "study.md", markdown)
    write_json(out / "study.json", table)
    return RecipeFits(fits, markdown, (out / "study.md", out / "study.json"))

