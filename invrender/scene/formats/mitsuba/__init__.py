"""Mitsuba 3 XML scene files: a documented subset of Mitsuba's scene format, read into invrender's
own scene objects (``load_scene("scene.xml")``, ``invrender render scene.xml``,
:func:`load_mitsuba_xml`).

Anything outside the subset is a :class:`~invrender.errors.SceneError` whose one-line message
names the file, the line, the element (tag and type) and what is supported, e.g.
``scene.xml:12: <emitter type="point">: unsupported emitter type 'point' (supported: area)``.
Out-of-range values (a reflectance of 1.5, a roughness of 0, a negative index of refraction) are
SceneErrors naming the line and the value too.

The subset, one module per part (each module's docstring is its reference):

- :mod:`.parser`: the file structure (``<scene>``, ``<default>`` and ``$name`` parameters, ids and
  ``<ref>``, ``<path>``, ``<include>``, the Mitsuba 0.x upgrade), the property elements and the
  transforms; a generic XML scene parser that knows no plugin. A scene with several problems gets
  one error listing them (the first five and a count).
- :mod:`.spectra`: spectra into linear sRGB as Mitsuba's RGB variants (CIE 1931 tables).
- :mod:`.shapes`: ``rectangle``, ``cube``, ``sphere``, ``disk``, ``cylinder``, ``obj``, ``ply``,
  ``serialized`` (:mod:`.serialized`: Mitsuba's mesh format).
- :mod:`.bsdfs`: BSDFs onto invrender's materials (and ``twosided``).
- :mod:`.textures`: colours and bitmap textures.
- :mod:`.emitters`: the emitters of the registry (``area``, nested or referenced; ``point``, ...).
- :mod:`.sensor`: ``perspective`` (``fov`` or ``focal_length``), ``thinlens`` and
  ``orthographic`` sensors, the film, filter and sampler.
- :mod:`.integrator`: ``path``, ``direct``, ``moment`` (its nested integrator), ``volpath`` /
  ``volpathmis`` (as ``path``: no media are read).
- :mod:`.subset`: the above as tables (the element and plugin types read), for listings such as
  ``bench/census.py``.
- :mod:`.loader`: the render settings a file suggests (``scene.defaults``), how materials and
  emitters are named, and the assembled scene.
"""

from invrender.scene.formats.mitsuba.bsdfs import NAMED_IOR
from invrender.scene.formats.mitsuba.loader import load_mitsuba_xml

__all__ = ["NAMED_IOR", "load_mitsuba_xml"]
