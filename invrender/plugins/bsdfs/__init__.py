"""The built-in materials, one module each; importing this package registers them in
:data:`invrender.registry.MATERIALS` (in this order, which the docs' tables and messages keep).

Each module is the only place its material is described: type name, differentiable parameters
with their kinds, constants with their ranges, lobe flags, the formats' aliases, and the BSDF's
``eval`` / ``pdf`` / ``sample``. A new material is one more module like these plus its import here
(or, outside the package, a module of the user's that registers its class).

The table of types (docs/plugins.md) is generated from these declarations
(:func:`invrender.scene.plugins.plugin_table`).
"""

from invrender.plugins.bsdfs import diffuse, mirror, dielectric, glossy, plastic, roughdielectric, thindielectric, principled, principledthin, pplastic, blend, mask  # noqa: F401  (registration order)
from invrender.plugins.bsdfs.dielectric import Dielectric
from invrender.plugins.bsdfs.blend import Blend
from invrender.plugins.bsdfs.diffuse import Diffuse
from invrender.plugins.bsdfs.glossy import Glossy
from invrender.plugins.bsdfs.mask import Mask
from invrender.plugins.bsdfs.mirror import Mirror
from invrender.plugins.bsdfs.principled import Principled
from invrender.plugins.bsdfs.principledthin import PrincipledThin
from invrender.plugins.bsdfs.plastic import Plastic, RoughPlastic, RoughPlasticGGX
from invrender.plugins.bsdfs.pplastic import PolarizedPlastic
from invrender.plugins.bsdfs.roughdielectric import RoughDielectric, RoughDielectricGGX
from invrender.plugins.bsdfs.thindielectric import ThinDielectric

__all__ = ["Diffuse", "Mirror", "Dielectric", "Glossy", "Plastic", "RoughPlastic", "RoughPlasticGGX", "RoughDielectric", "RoughDielectricGGX", "ThinDielectric", "Principled", "PrincipledThin", "PolarizedPlastic", "Blend", "Mask"]
