"""The integrator base class, its registry, and the settings every bounce-loop integrator shares.

An integrator is an estimator of the Neumann series ``g eps + gMg eps + g(Mg)^2 eps + ...`` (or of a
truncation of it). Subclasses name themselves (``name``), declare a frozen settings dataclass
(``Settings``) that validates itself, and write only :meth:`Integrator.trace`, which follows one
chunk of paths. The base class owns the chunked driver (:meth:`Integrator.render`); one that needs a
pre-pass overrides :meth:`Integrator.prepare`, one whose paths split calls ``film.branch`` and
:meth:`~invrender.core.context.PathState.cat` inside its trace.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import torch

from invrender import registry
from invrender.errors import ParameterError, did_you_mean
from invrender.scene.scene import Scene
from invrender import first_use
from invrender.core import fused
from invrender.core.queries import RepeatedQueries
from invrender.core.bsdfs import BSDFSampling
from invrender.core.context import PathState, TransportContext
from invrender.core.driver import (
    BYTES_PER_PATH,
    BYTES_PER_REPLAYED_PATH,
    RenderSettings,
    check_film_memory,
    cpu_workers,
    for_each_chunk,
)
from invrender.core.film import Film, PathFilm
from invrender.validate import check_bool, check_depth, check_paths, type_names

#: integrator name -> class, filled by subclassing :class:`Integrator` (the package's registry)
INTEGRATORS = registry.INTEGRATORS


@dataclass(frozen=True)
class DepthSettings:
    """Settings of an integrator that truncates the series.

    Attributes:
        max_depth: Neumann terms kept, counted as Mitsuba counts: 1 = emitters seen directly,
            2 = + direct illumination, ...; -1 = unbounded (ended by Russian roulette only).
        hide_emitters: the camera does not see emitters directly (Mitsuba's hide_emitters): black
            where it would see an environment, what lies behind where it would see an emitting
            shape; emitters still light the scene and show in reflections.
    """

    max_depth: int = 8
    hide_emitters: bool = False

    def __post_init__(self):
        check_depth("", "max_depth", self.max_depth)
        check_bool("", "hide_emitters", self.hide_emitters)

    def continues_after(self, depth: int) -> bool:
        """May a path whose last vertex has index ``depth`` (0 = first hit) add terms beyond ``depth``?"""
        return self.max_depth == -1 or depth + 1 < self.max_depth


@dataclass(frozen=True)
class RouletteSettings(DepthSettings):
    """Settings of an integrator with Russian roulette.

    Attributes:
        max_depth: as :class:`DepthSettings`.
        rr_depth: Russian roulette starts after this many terms (Mitsuba's ``rr_depth``, default 5);
            -1 = never (no roulette: paths end at ``max_depth``, which must then be finite).
    """

    rr_depth: int = 5

    def __post_init__(self):
        super().__post_init__()
        check_depth("", "rr_depth", self.rr_depth, "no Russian roulette")
        if self.rr_depth == -1 and self.max_depth == -1:
            raise ParameterError("max_depth -1 (unbounded) needs Russian roulette to end paths: give rr_depth >= 1 or a finite max_depth")


@dataclass(frozen=True)
class SamplingSettings(RouletteSettings):
    """Settings of an integrator that follows BSDF samples, with Russian roulette.

    Attributes:
        max_depth, rr_depth: as :class:`RouletteSettings`.
        hemisphere: how diffuse BSDFs draw directions: ``"cosine"`` (default) or ``"uniform"``
            (:class:`~invrender.core.bsdfs.BSDFSampling`; docs/sampling.md).
    """

    hemisphere: str = "cosine"

    def __post_init__(self):
        super().__post_init__()
        BSDFSampling(self.hemisphere)  # validates


@dataclass(frozen=True)
class MitsubaAlias:
    """A Mitsuba integrator plugin an integrator stands for with some of its settings fixed, where
    the two estimate the same image (``Integrator.mitsuba_aliases``; Mitsuba's ``direct`` is
    :class:`~invrender.plugins.integrators.path.Path` at ``max_depth`` 2).

    Attributes:
        settings: the settings it fixes (the element may not give them).
        passed: the settings the element may give by name (``hide_emitters``).
        counts: integer properties of the Mitsuba plugin that change only the variance where they
            lie in ``[low, high]`` (``high`` None: no bound) and are then read and ignored:
            name -> ``(low, high, why)``; outside, an error saying ``why``.
    """

    settings: dict
    passed: tuple = ("hide_emitters",)
    counts: dict = dataclasses.field(default_factory=dict)

    def describe(self) -> str:
        """The fixed settings as the docs' tables show them (``max_depth = 2``)."""
        return ", ".join(f"{k} = {v!r}" for k, v in self.settings.items())


class Integrator(ABC):
    """Base class: a named estimator with validated settings and the default chunked driver.

    Construct with the settings' fields as keywords (``Path(max_depth=4)``), or by name through
    :func:`make_integrator`. Unknown keywords are errors naming the integrator's settings.
    """

    #: the name ``render(integrator=...)``, the CLI and recipes use
    name: ClassVar[str]
    #: the frozen settings dataclass
    Settings: ClassVar[type] = DepthSettings
    #: one line for ``--help`` and error messages
    summary: ClassVar[str] = ""
    #: why the estimate is not a polynomial in the parameters (path records refuse it); None = it is
    not_recordable: ClassVar[str | None] = None
    #: Mitsuba integrator plugins it stands for with some settings fixed: plugin -> :class:`MitsubaAlias`
    #: (read from the class body itself, as ``mitsuba_plugins`` is)
    mitsuba_aliases: ClassVar[dict] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__:
            INTEGRATORS.register(cls)

    def __init__(self, **options):
        known = {f.name for f in dataclasses.fields(self.Settings)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ParameterError(f"integrator {self.name!r} has no setting {unknown[0]!r}{did_you_mean(unknown[0], known)} (its settings: {', '.join(sorted(known)) or 'none'})")
        self.settings = self.Settings(**options)

    def __repr__(self) -> str:
        fields = ", ".join(f"{k}={v!r}" for k, v in dataclasses.asdict(self.settings).items())
        return f"{type(self).__name__}({fields})"

    @property
    def terms_kept(self) -> int:
        """Largest number of Neumann terms this integrator can produce (-1 = unbounded)."""
        return self.settings.max_depth

    @property
    def bsdf_sampling(self) -> BSDFSampling:
        """How the BSDFs of this integrator's renders draw directions: the settings' ``hemisphere``
        where they have one (:class:`SamplingSettings`), else the default (cosine-weighted)."""
        return BSDFSampling(getattr(self.settings, "hemisphere", "cosine"))

    def prepare(self, ctx: TransportContext) -> TransportContext:
        """Pre-pass hook, run once per render before any chunk is traced: return the context the
        chunks are traced with (e.g. with ``extra`` holding a radiosity solution). Default: none."""
        return ctx

    @abstractmethod
    def trace(self, ctx: TransportContext, state: PathState, film: Film) -> None:
        """Follow ``state``'s camera rays and add their contributions to ``film`` (per Neumann term)."""

    def context(self, scene: Scene, settings: RenderSettings, device: torch.device, params: dict | None = None) -> TransportContext:
        """The prepared :class:`TransportContext` of one render."""
        # one Embree thread per query where the render's workers share the cores, or where this
        # thread's torch is single-threaded (driver.one_thread: renders traced side by side)
        threads = 1 if cpu_workers(device) > 1 or (device.type == "cpu" and torch.get_num_threads() == 1) else None
        with first_use.announcing(settings.progress):  # a first use's compiles say so where progress shows
            ctx = TransportContext.build(scene, device, settings.backend, threads, params, self.bsdf_sampling, settings.sampling_params)
        if getattr(self.settings, "hide_emitters", False):  # settings without it (a plugin's own) show emitters
            ctx = dataclasses.replace(ctx, hide_emitters=True)
        return self.prepare(ctx)

    def render(
        self, scene: Scene, settings: RenderSettings, device: torch.device, params: dict | None = None, keep: dict | None = None, tangents: dict | None = None
    ) -> torch.Tensor:
        """The image: (H, W, 3), or (K, H, W, 3) per term with ``settings.terms``; records autograd
        where a parameter requires grad (``params`` overrides ``scene.params`` values).

        ``keep``: a dict that receives each chunk's per-path radiance and its shadow rays' answers,
        ``{first path id: ((paths + branches, 3) float32, RepeatedQueries)}`` (:meth:`PathFilm.totals`,
        rounded; the answers as bits), for path replay to reuse instead of tracing the paths again
        and casting their shadow rays, chunked as replay chunks them; the image is the same (not
        with ``terms``).
        """
        if (keep is not None or tangents is not None) and settings.terms:
            raise ValueError("keep, tangents: kept for full images only, not per term")
        check_paths(scene.width, scene.height, settings.spp)
        check_film_memory(scene.width, scene.height, device, max(self.terms_kept, 1) if settings.terms else 1)
        ctx = self.context(scene, settings, device, params)
        scene_tables = self.fused_scene(ctx)
        box = scene.film.is_box
        if tangents is not None:
            if scene_tables is None or scene_tables.rho is None or not box:
                raise ValueError(f"tangents: the fused bounce's per-pixel Jacobian does not apply to this render of {scene.name!r}")
            films = [fused.TangentFilm(scene.width, scene.height, fused.slots(scene_tables), device) for _ in range(cpu_workers(device))]
        else:
            films = [Film(scene.width, scene.height, settings.terms, device, scene.film.filter) for _ in range(cpu_workers(device))]

        def chunk(worker: int, state: PathState, start: int, xy: torch.Tensor) -> None:
            if keep is None and box:
                self.trace(ctx, state, films[worker])
                return
            # per-path radiance first: kept for replay, and/or splatted by the filter from the film positions
            paths, shadows = PathFilm(state.count, device, settings.terms), RepeatedQueries(ctx.accel, kinds=("occluded",))
            self.trace(ctx if keep is None else dataclasses.replace(ctx, accel=shadows), state.replace(pixel=torch.arange(state.count, device=device)), paths)
            if settings.terms:  # (a filter's: never kept) each term's radiance splatted on its own
                films[worker].splat(xy, {k: t[: state.count] for k, t in paths.term_totals().items()})
                return
            totals = paths.totals()  # a root path's total holds its branches'
            if box:
                films[worker].add(0, state.pixel, totals[: state.count])
            else:
                films[worker].splat(xy, {0: totals[: state.count]})
            if keep is not None:
                keep[start] = (totals.float(), shadows)  # float32 until replay takes it up

        small = keep is None and device.type == "cpu" and scene_tables is not None  # fused chunks need not be large
        size = fused.BYTES_PER_PATH if small else BYTES_PER_PATH if keep is None else BYTES_PER_REPLAYED_PATH  # kept chunks are replay's chunks
        cap = fused.CPU_TANGENT_CHUNK_PATHS if tangents is not None else fused.CPU_CHUNK_PATHS
        for_each_chunk(scene, settings, device, chunk, across_ranks=True, with_start=True, bytes_per_path=size, max_chunk=cap if small else None, with_positions=True)
        film = type(films[0]).merge(films).summed_across_ranks()
        if tangents is not None:
            tangents["jacobian"] = film.jacobian / settings.spp
        return film.develop(settings.spp, max(self.terms_kept, 1))

    def fused_scene(self, ctx: TransportContext):
        """The fused primal bounce's view of the render ``ctx`` (:func:`invrender.core.fused.tables`),
        None where it does not apply (always for integrators without a random walk's bounce)."""
        return fused.scene_of(ctx, getattr(self, "fused_direct", None), self.bsdf_sampling.hemisphere)


def make_integrator(integrator="path", **options) -> Integrator:
    """An :class:`Integrator` from a spec (a name, a ``{"type": name, ...}`` mapping or an instance;
    :func:`invrender.registry.integrator_spec`) and settings given beside it (none beside an instance)."""
    if isinstance(integrator, Integrator):
        if options:
            raise ParameterError(f"settings {', '.join(sorted(options))} given beside an integrator object: set them on the object")
        return integrator
    name, settings = registry.integrator_spec(integrator)
    return INTEGRATORS[name](**{**settings, **options})


@dataclass(frozen=True)
class SettingDoc:
    """One field of an integrator's settings, for help texts and for reading values from text.

    Attributes:
        name: the field's name (a key of the integrator spec).
        kind: its type as written in the dataclass (``"int"``, ``"float | None"``, ...).
        default: its default value.
        doc: its line of the settings' docstring (its ``Attributes`` section).
    """

    name: str
    kind: str
    default: object
    doc: str


def setting_docs(cls) -> list[SettingDoc]:
    """The settings of the integrator class ``cls`` (or a settings dataclass), with each field's
    doc read from the ``Attributes`` section of the first class in the settings' MRO that documents
    it other than as ``as :class:...`` (a subclass's "max_depth: as DepthSettings")."""
    settings = cls.Settings if isinstance(cls, type) and issubclass(cls, Integrator) else cls
    docs: dict[str, str] = {}
    for klass in settings.__mro__:
        for names, text in _attribute_docs(klass.__doc__ or "").items():
            for name in names:
                if name not in docs and not text.startswith("as "):
                    docs[name] = text
    return [
        SettingDoc(f.name, " | ".join(type_names(f.type)), f.default if f.default is not dataclasses.MISSING else None, docs.get(f.name, ""))
        for f in dataclasses.fields(settings) if f.init
    ]  # fmt: skip


def _attribute_docs(docstring: str) -> dict[tuple[str, ...], str]:
    """``Attributes:`` entries of a Google-style docstring: (names, ...) -> text on one line."""
    import inspect
    import re

    lines = inspect.cleandoc(docstring).splitlines()
    out: dict[tuple[str, ...], list[str]] = {}
    inside, current, indent = False, None, None
    for line in lines:
        if line.strip() == "Attributes:":
            inside = True
            continue
        if not inside:
            continue
        if line and not line.startswith(" "):
            break  # the section ended
        entry = re.match(r"^(\s+)([a-z_][a-z0-9_]*(?:, [a-z_][a-z0-9_]*)*): ?(.*)$", line)
        if entry and (indent is None or len(entry.group(1)) == indent):
            indent = len(entry.group(1))
            current = tuple(entry.group(2).split(", "))
            out[current] = [entry.group(3)]
        elif current is not None and line.strip():
            out[current].append(line.strip())
    return {names: re.sub(r"``|:\w+:`~?(?:[\w.]*\.)?(\w+)`", lambda m: m.group(1) or "", " ".join(parts)).strip() for names, parts in out.items()}


def setting_from_text(integrator, key: str, text: str):
    """The value of setting ``key`` of ``integrator`` (a registered name or class) read from text
    as the settings dataclass's field type says: an int, a float, ``true``/``false``, a string, or
    ``none`` for a field that may be None. A one-line :class:`ParameterError` for an unknown key
    or text that is not of the field's type (the value's range is checked by the settings)."""
    cls = INTEGRATORS.get(integrator) if isinstance(integrator, str) else integrator
    fields = {d.name: d for d in setting_docs(cls)}
    if key not in fields:
        raise ParameterError(f"integrator {cls.name!r} has no setting {key!r} (its settings: {', '.join(sorted(fields)) or 'none'})")
    kinds = [k.strip() for k in fields[key].kind.split("|")]
    lowered = text.strip().lower()
    if "None" in kinds and lowered in ("none", "null"):
        return None
    for kind in kinds:
        if kind == "bool" and lowered in ("true", "false", "yes", "no", "1", "0"):
            return lowered in ("true", "yes", "1")
        if kind in ("int", "float"):
            try:
                return int(text) if kind == "int" else float(text)
            except ValueError:
                continue
        if kind == "str":
            return text
    raise ParameterError(f"integrator {cls.name!r} setting {key} must be {' or '.join(k if k != 'None' else 'none' for k in kinds)}, got {text!r}")


def integrators_table() -> str:
    """A Markdown table of every registered integrator: name, what it is, its settings (name,
    default, doc), generated from the registry and the settings dataclasses (the docs' table)."""
    rows = ["| integrator | what it is | settings | Mitsuba XML |", "|---|---|---|---|"]
    for name, cls in INTEGRATORS.items():
        settings = "<br>".join(f"`{d.name}` = `{d.default!r}`: {d.doc}".rstrip(": ") for d in setting_docs(cls))
        mitsuba = ", ".join([f"`{m}`" for m in vars(cls).get("mitsuba_plugins", ())] + [f"`{m}` ({a.describe()})" for m, a in vars(cls).get("mitsuba_aliases", {}).items()])
        rows.append(f"| `{name}` | {cls.summary.removeprefix(f'{name}: ')} | {settings or '--'} | {mitsuba or '--'} |")
    return "\n".join(rows) + "\n"


def integrators_help(width: int = 100, names=None) -> str:
    """Every registered integrator (or those of ``names``) with its summary and its settings
    (name, default, doc), for the command line's ``--help``; generated from the registry and the
    settings dataclasses (into :mod:`invrender.cli.catalog`)."""
    import textwrap

    lines = []
    for name, cls in INTEGRATORS.items():
        if names is not None and name not in names:
            continue
        summary = cls.summary.removeprefix(f"{name}: ")  # some summaries start with their name
        lines.append(f"  {name}: {summary}" if summary else f"  {name}")
        for d in setting_docs(cls):
            head = f"    {d.name} = {d.default!r}"
            lines += textwrap.wrap(d.doc, width, initial_indent=f"{head:<32} " if len(head) < 32 else head + " ", subsequent_indent=" " * 33) or [head]
    return "\n".join(lines)
