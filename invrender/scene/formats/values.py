"""What every format's checks share: is a value a number, how an error message shows it, and the
procedural textures they bake (:func:`checkerboard`)."""

from __future__ import annotations

import numpy as np


def is_number(x) -> bool:
    """An int or float, not a bool."""
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def one_line(x) -> str:
    """``str(x)`` with its whitespace runs (newlines too) collapsed to single spaces."""
    return " ".join(str(x).split())


def show(value) -> str:
    """``repr(value)`` on one line, cut to 60 characters: how a message quotes an input value."""
    text = repr(value)
    return one_line(text if len(text) <= 60 else text[:57] + "...")


# ---------------------------------------------------------------- procedural textures, baked

#: texels per side of a baked checkerboard (:func:`checkerboard`) unless a format says otherwise
CHECKERBOARD_RESOLUTION = 512


def checkerboard(color0, color1, to_uv=None, resolution: int = CHECKERBOARD_RESOLUTION):
    """Mitsuba 3's ``checkerboard`` texture baked into a linear (resolution, resolution, 3) float64
    image, row 0 at the top as images are stored.

    Mitsuba's rule: with ``(s, t) = to_uv (u, v)``, a point is ``color0`` where
    ``frac(s) > 0.5`` and ``frac(t) > 0.5`` agree (both or neither), else ``color1``, in Mitsuba's
    texture coordinates (``v = 0`` at the image's top row, which is how invrender's lookups read
    an image: a baked board lands where Mitsuba draws it). Texel (i, j) takes the colour at its
    centre ``(u, v) = ((j + 0.5) / resolution, (i + 0.5) / resolution)``.

    Exactness: bilinear filtering, as for every texture, blends the two colours within half a
    texel of a cell edge; everywhere else the value is exactly Mitsuba's when the cell edges fall
    on texel edges (``to_uv`` a scale ``s`` with ``2 s`` dividing ``resolution``, offsets by
    multiples of ``1 / resolution``), and the mean over a cell is kept. The board is baked over
    ``[0, 1]^2`` and repeats beyond it, which is Mitsuba's board only when ``to_uv`` makes it
    periodic with period 1 (an integer scale).

    Args:
        color0, color1: RGB triples (3,) (or one number, grey).
        to_uv: a (3, 3) or (4, 4) matrix acting on ``(u, v, 1)`` (Mitsuba's ``to_uv``; of a 4 x 4,
            rows and columns 0, 1 and 3 are used, as Mitsuba reads a 4 x 4 as a 2D transform);
            None = the identity.
        resolution: texels per side.
    """
    m = np.eye(3) if to_uv is None else np.asarray(to_uv, dtype=np.float64)
    if m.shape == (4, 4):
        m = m[np.ix_([0, 1, 3], [0, 1, 3])]
    c = (np.arange(resolution, dtype=np.float64) + 0.5) / resolution
    u, v = np.meshgrid(c, c)  # u along columns, v down the rows
    s = m[0, 0] * u + m[0, 1] * v + m[0, 2]
    t = m[1, 0] * u + m[1, 1] * v + m[1, 2]
    first = ((s - np.floor(s)) > 0.5) == ((t - np.floor(t)) > 0.5)
    c0 = np.broadcast_to(np.asarray(color0, dtype=np.float64), (3,))
    c1 = np.broadcast_to(np.asarray(color1, dtype=np.float64), (3,))
    return np.where(first[:, :, None], c0, c1)
