"""One exception hierarchy for everything a user can get wrong.

Every error raised on bad input is a subclass of :class:`InvRenderError`, and its message names the
file, key or value at fault and what was expected, on one line. The CLI prints that line and exits
with status 2.
"""

import difflib


def did_you_mean(name: str, choices) -> str:
    """`` (did you mean 'x'?)`` for the choice closest to the unknown ``name`` (difflib's ratio,
    as argparse and Python's own NameError suggest), or ``""`` when nothing is close. Appended to
    the one-line message of an unknown scene, parameter, integrator, plugin or command name."""
    close = difflib.get_close_matches(str(name), [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


class InvRenderError(Exception):
    """Base class of every error invrender raises on bad input."""


class SceneError(InvRenderError):
    """A scene file, built-in scene name, mesh or scene setting is missing or invalid."""


class ImageError(InvRenderError):
    """An image file is missing, corrupt, of the wrong shape, or cannot be written."""


class ParameterError(InvRenderError):
    """A parameter name, value or render setting is unknown or out of range."""


class UnknownParameterError(ParameterError, KeyError):
    """A parameter name a scene does not have: a :class:`ParameterError` and, as the lookup of a
    missing key in ``scene.params``, a ``KeyError`` too (``except KeyError`` still catches it)."""

    def __str__(self) -> str:  # the message as given (KeyError's own quotes it)
        return str(self.args[0]) if self.args else ""


class MissingPackageError(InvRenderError):
    """An optional package (warp-lang, embreex, pyrender) that a path needs is not installed."""


class BaselineError(InvRenderError):
    """A baseline renderer (pyrender) or an OpenGL context for it is not available."""


class NonFiniteError(InvRenderError):
    """A render or a fit produced a non-finite value (NaN or inf radiance, loss or parameter); the
    message names where: the pixel count, the parameter, the step."""
