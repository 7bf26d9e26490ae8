"""Plugin registries: where materials, emitters, integrators and reconstruction filters are found by name.

A plugin is one module that describes itself completely (its type name, parameters, settings,
aliases in the scene formats) and registers its class here with one decorator or by subclassing.
Everything that needs to know the plugins (loaders, format mappings, the CLI's help, error
messages, the docs' tables) reads these registries instead of keeping a list of its own, so adding
a plugin is one new file plus its registration.

This module sits at the bottom of the package's layers: it stores classes and imports none at
module level. The plugins register when their modules are imported: each registry imports its
package of built-in plugins (by name, as an entry point would be loaded) the first time it is
used, so a lookup always sees them and a user's plugin, registered after them, may shadow one;
``import invrender`` itself imports no plugin (nor torch) until the API is used.

The configuration spec of an integrator has three spellings, accepted everywhere a render is
configured (``render``, ``fit``, studies, ablations, recipes, the CLI)::

    "path"                                             # a name: its default settings
    {"type": "path", "max_depth": 8, "rr_depth": 3}    # a name and settings
    Path(max_depth=8)                                  # an instance
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from typing import Generic, TypeVar

from invrender.errors import InvRenderError, ParameterError, SceneError, did_you_mean

T = TypeVar("T")


class Registry(Generic[T]):
    """Classes by name, for one kind of plugin.

    Args:
        what: what a name names, for messages (``"material type"``).
        error: the :class:`~invrender.errors.InvRenderError` subclass an unknown name raises.
        attribute: the class attribute holding a plugin's name (``"type_name"``, ``"name"``).
        builtins: the package whose import registers the built-in plugins, imported on first use
            of the registry (None: none).
    """

    def __init__(self, what: str, error: type[InvRenderError], attribute: str, builtins: str | None = None):
        self.what, self.error, self.attribute = what, error, attribute
        self._builtins = builtins
        self._by_name: dict[str, type[T]] = {}

    @property
    def _classes(self) -> dict[str, type[T]]:
        """The classes by name, the built-in plugins' package imported first (once: a lookup made
        while it is being imported sees those registered so far)."""
        if self._builtins is not None:
            package, self._builtins = self._builtins, None
            try:
                importlib.import_module(package)
            except BaseException:
                self._builtins = package  # tried again at the next use
                raise
        return self._by_name

    def loaded_names(self) -> list[str]:
        """The names registered so far, without importing the built-in plugins (the command line's
        early checks: its static list of built-in names plus these)."""
        return list(self._by_name)

    def register(self, cls: type[T]) -> type[T]:
        """Register ``cls`` under its name (usable as a class decorator); registering another
        class under a taken name replaces it (a user's plugin may shadow a built-in one)."""
        name = getattr(cls, self.attribute, None)
        if not isinstance(name, str) or not name:
            raise TypeError(f"{cls.__name__} needs a non-empty string {self.attribute!r} to be registered as a {self.what}")
        self._classes[name] = cls
        return cls

    def unregister(self, name: str) -> None:
        """Forget ``name`` (tests that register a plugin of their own clean up with this)."""
        self._classes.pop(name, None)

    def get(self, name, where: str = "") -> type[T]:
        """The class called ``name``; a one-line error naming ``where`` and the known names otherwise.

        A name with arguments, ``"base(arg, ...)"``, is the class ``base`` builds for them with its
        ``variant(name, where)`` (a material made of nested materials, ``"blendbsdf(diffuse,mirror)"``):
        found, not listed (iterating the registry sees the registered names only)."""
        if isinstance(name, str) and "(" in name and name not in self._classes:
            base = self._classes.get(name.partition("(")[0].strip())
            if base is not None and hasattr(base, "variant"):
                return base.variant(name, where)
        if not isinstance(name, str) or name not in self._classes:
            prefix = f"{where}: " if where else ""
            raise self.error(f"{prefix}unknown {self.what} {name!r}{did_you_mean(name, self._classes) if isinstance(name, str) else ''} (known: {', '.join(self._classes)})")
        return self._classes[name]

    def __getitem__(self, name: str) -> type[T]:
        return self.get(name)

    def __contains__(self, name) -> bool:
        return name in self._classes

    def __iter__(self) -> Iterator[str]:
        return iter(self._classes)

    def __len__(self) -> int:
        return len(self._classes)

    def items(self):
        return self._classes.items()

    def values(self):
        return self._classes.values()

    def names(self) -> list[str]:
        return list(self._classes)

    def pop(self, name: str, default=None):
        return self._classes.pop(name, default)


#: material type name -> its plugin class (:mod:`invrender.plugins.bsdfs`)
MATERIALS: Registry = Registry("material type", SceneError, "type_name", builtins="invrender.plugins.bsdfs")
#: emitter type name -> its plugin class (:mod:`invrender.plugins.emitters`)
EMITTERS: Registry = Registry("emitter type", SceneError, "type_name", builtins="invrender.plugins.emitters")
#: integrator name -> its class (:mod:`invrender.plugins.integrators`; registered by subclassing)
INTEGRATORS: Registry = Registry("integrator", ParameterError, "name", builtins="invrender.plugins.integrators")
#: reconstruction filter name -> its class (:mod:`invrender.plugins.filters`)
FILTERS: Registry = Registry("reconstruction filter", ParameterError, "type_name", builtins="invrender.plugins.filters")


def integrator_spec(spec, where: str = "integrator") -> tuple[str, dict]:
    """``(name, settings)`` of an integrator spec given as a name or a ``{"type": name, ...}``
    mapping (an instance is handled by the caller); a one-line :class:`ParameterError` otherwise."""
    if isinstance(spec, str):
        INTEGRATORS.get(spec, where)
        return spec, {}
    if isinstance(spec, Mapping):
        options = dict(spec)
        if "type" not in options:
            raise ParameterError(f"{where}: a mapping spec needs a 'type' key naming the integrator (known: {', '.join(INTEGRATORS)}), got keys {sorted(options)}")
        name = options.pop("type")
        INTEGRATORS.get(name, where)
        return name, options
    raise ParameterError(f"{where}: expected an integrator name, a {{'type': name, ...}} mapping or an integrator object, got {spec!r}")


def make_filter(spec, where: str = "filter"):
    """A reconstruction filter object (:mod:`invrender.plugins.filters`) from a spec: None (the
    box), a name, a ``{"type": name, ...}`` mapping of its settings, or a filter object (returned
    as it is); a one-line :class:`ParameterError` naming ``where`` for an unknown name, an unknown
    setting or a value out of range."""
    if spec is None:
        spec = "box"
    if isinstance(spec, str):
        return FILTERS.get(spec, where)()
    if isinstance(spec, Mapping):
        settings = dict(spec)
        if "type" not in settings:
            raise ParameterError(f"{where}: a mapping spec needs a 'type' key naming the filter (known: {', '.join(FILTERS)}), got keys {sorted(settings)}")
        cls = FILTERS.get(settings.pop("type"), where)
        unknown = sorted(set(settings) - set(cls.setting_names))
        if unknown:
            raise ParameterError(f"{where}: filter {cls.type_name!r} has no setting {unknown[0]!r}{did_you_mean(unknown[0], cls.setting_names)} (its settings: {', '.join(cls.setting_names) or 'none'})")
        try:
            return cls(**settings)
        except ParameterError as e:
            raise ParameterError(f"{where}: {e}") from None
    if callable(getattr(spec, "footprint", None)):
        return spec
    raise ParameterError(f"{where}: expected a filter name, a {{'type': name, ...}} mapping or a filter object, got {spec!r}")
