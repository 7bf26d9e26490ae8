"""The UV tangent frame (:mod:`invrender.core.shading`) against Mitsuba 3.9.1's shading frames:
``si.sh_frame`` at hits of a bent quad read from an OBJ file with texture coordinates and vertex
normals (s from dp/du, made orthogonal to the interpolated normal) and without either (s along
the edge p1 - p0, Mitsuba's barycentric parameterization)."""

from __future__ import annotations

import json

import pytest
import torch

import invrender as ir
from invrender.core.context import TransportContext
from invrender.core.surface import surface_at

OBJ_UV = "v -1 -1 0.2\nv 1 -0.8 0\nv 0.9 1 -0.3\nv -1.1 0.9 0.1\nvt 0.1 0.2\nvt 0.9 0.1\nvt 0.8 0.7\nvt 0.2 0.9\nvn 0.1 0.2 1\nvn -0.1 0 1\nvn 0 -0.2 1\nvn 0.2 0.1 1\nf 1/1/1 2/2/2 3/3/3\nf 1/1/1 3/3/3 4/4/4\n"
OBJ_BARE = "v -1 -1 0.2\nv 1 -0.8 0\nv 0.9 1 -0.3\nv -1.1 0.9 0.1\nf 1 2 3\nf 1 3 4\n"
#: rays and Mitsuba's ``si.sh_frame`` s and n at their hits (``scene.ray_intersect``, llvm_ad_rgb), each file
#: under an anisotropic roughconductor
MITSUBA = json.loads('''{"origin": [[0.566004, 0.269529, 3.0], [0.218391, -0.357038, 3.0], [-0.335283, -0.239957, 3.0], [0.090168, -0.64567, 3.0], [-0.341491, 0.499011, 3.0], [0.382843, -0.418588, 3.0]], "d": [[-0.066482, 0.033241, -0.997234], [-0.066482, 0.033241, -0.997234], [-0.066482, 0.033241, -0.997234], [-0.066482, 0.033241, -0.997234], [-0.066482, 0.033241, -0.997234], [-0.066482, 0.033241, -0.997234]], "uv": {"s": [[0.971962, 0.235052, -0.006373], [0.968756, 0.24561, -0.034459], [0.943432, 0.312103, -0.111926], [0.967591, 0.248654, -0.044034], [0.942546, 0.306915, -0.131951], [0.969226, 0.245836, -0.012848]], "n": [[0.025741, -0.079421, 0.996509], [0.029632, 0.023325, 0.999289], [0.09182, 0.078437, 0.992681], [0.027983, 0.067719, 0.997312], [0.127244, 0.035391, 0.99124], [0.009197, 0.015992, 0.99983]]}, "bare": {"s": [[0.98472, 0.093443, -0.146955], [0.985546, 0.093846, -0.141042], [0.677708, 0.713376, -0.178344], [0.986033, 0.094134, -0.137397], [0.677708, 0.713376, -0.178344], [0.986378, 0.094364, -0.134736]], "n": [[0.135715, 0.117024, 0.983812], [0.129064, 0.123373, 0.983932], [0.149332, 0.103962, 0.983307], [0.124958, 0.127281, 0.983964], [0.16851, 0.085413, 0.981992], [0.121958, 0.130132, 0.983968]]}}''')
SCENE = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/><transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>
  <shape type="obj"><string name="filename" value="{name}.obj"/><bsdf type="roughconductor"><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/></bsdf></shape>
</scene>"""


@pytest.mark.parametrize("name", ["uv", "bare"])
def test_the_tangent_frame_is_mitsubas(name, tmp_path):
    (tmp_path / f"{name}.obj").write_text(OBJ_UV if name == "uv" else OBJ_BARE)
    (tmp_path / "scene.xml").write_text(SCENE.format(name=name))
    scene = ir.load_scene(str(tmp_path / "scene.xml"), resolution=(4, 4))
    ctx = TransportContext.build(scene, torch.device("cpu"))
    o, d = torch.tensor(MITSUBA["origin"]), torch.tensor(MITSUBA["d"])
    s = surface_at(ctx.triangles, ctx.accel.intersect(o, d), d)
    sp = ctx.shading_point(s, -d)
    expected = MITSUBA[name]
    assert torch.allclose(sp.frame.n, torch.tensor(expected["n"]), atol=2e-5)
    assert torch.allclose(sp.frame.s, torch.tensor(expected["s"]), atol=2e-5)
    assert torch.allclose(sp.frame.t, torch.linalg.cross(sp.frame.n, sp.frame.s), atol=1e-6)
