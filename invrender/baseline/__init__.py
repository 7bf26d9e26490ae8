"""Independent baselines rendered by other programs.

``pyrender_render`` rasterizes an invrender :class:`~invrender.scene.scene.Scene` with pyrender
(OpenGL): emitters seen directly, direct light from emitters approximated by small lights (with
shadow maps) and a constant ambient term, i.e. the Utah approximation ``g eps + g M eps0`` computed
by a program that shares no code with invrender's Monte Carlo integrators.
"""

from invrender.baseline.pyrender_baseline import LightPoint, emitter_lights, pyrender_brdf_cos, pyrender_render
from invrender.errors import BaselineError

__all__ = ["pyrender_render", "emitter_lights", "pyrender_brdf_cos", "LightPoint", "BaselineError"]
