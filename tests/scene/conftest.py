"""What the Mitsuba XML tests share: a small sensor and a scene file around a body."""

from __future__ import annotations

SENSOR = """
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
    </sensor>"""


def write_scene(path, body, version="3.0.0", sensor=True):
    """A scene file at ``path``: ``body`` inside <scene> (line 1), after :data:`SENSOR` (unless
    ``sensor`` is false); its folders are made."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'<scene version="{version}">' + (SENSOR if sensor else "") + body + "\n</scene>\n")
    return path
