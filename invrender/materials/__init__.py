"""The built-in materials, one module each; importing this package registers them in
:data:`invrender.registry.MATERIALS` (in this order, which the docs' tables and messages keep).

Each module is the only place its material is described: type name, differentiable parameters
with their kinds, constants with their ranges, lobe flags, the formats' aliases, and the BSDF's
``eval`` / ``pdf`` / ``sample``. A new material is one more module like these plus its import here
(or, outside the package, a module of the user's that registers its class).

=============  =========================================  ==========================================
type           differentiable parameters                  constants
=============  =========================================  ==========================================
``diffuse``    ``reflectance`` rho (RGB or texture),      --
               default 0.5
``mirror``     ``specular_reflectance`` (RGB), default 1  --
``dielectric`` --                                         ``ior`` > 0, interior over exterior
                                                          (exterior 1.0), default 1.5
``glossy``     ``specular_reflectance`` (RGB), default 1  ``roughness`` GGX alpha in (0, 1],
                                                          default 0.1
=============  =========================================  ==========================================

They correspond to Mitsuba 3's ``diffuse``, ``conductor`` and ``roughconductor`` with
``material = "none"`` (Fresnel 1), and smooth ``dielectric``.
"""

from invrender.materials import diffuse, mirror, dielectric, glossy  # noqa: F401  (registration order)
from invrender.materials.dielectric import Dielectric
from invrender.materials.diffuse import Diffuse
from invrender.materials.glossy import Glossy
from invrender.materials.mirror import Mirror

__all__ = ["Diffuse", "Mirror", "Dielectric", "Glossy"]
