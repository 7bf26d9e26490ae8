"""The built-in emitters, one module each; importing this package registers them in
:data:`invrender.registry.EMITTERS`.

Each module is the only place its emitter type is described: type name, differentiable parameters
with their kinds, constants, whether it emits from surfaces or from infinitely far, and its
queries (:class:`~invrender.core.lights.Light`). A new emitter type is one more module like
these plus its import here (or, outside the package, a module of the user's that registers its
class).

The table of types (docs/plugins.md) is generated from these declarations
(:func:`invrender.scene.plugins.plugin_table`).
"""

from invrender.plugins.emitters.area import Area
from invrender.plugins.emitters.constant import Constant
from invrender.plugins.emitters.envmap import Envmap

from invrender.plugins.emitters.point import Point
from invrender.plugins.emitters.spot import Spot
from invrender.plugins.emitters.directional import Directional
from invrender.plugins.emitters.projector import Projector

__all__ = ["Area", "Constant", "Envmap", "Point", "Spot", "Directional", "Projector"]
