"""Scenes: geometry as tensors, named materials/emitters, camera; built-ins and the file formats (:mod:`.formats`)."""

from __future__ import annotations

from pathlib import Path

from invrender.errors import SceneError, did_you_mean
from invrender.scene import formats
from invrender.scene.builtin import BUILTIN_SCENES, builtin_scene
from invrender.scene.camera import Camera
from invrender.scene.scene import Scene, build_scene
from invrender.scene.shapes import Mesh


def load_scene(source, resolution=None, device=None, ambient=None, studio: bool | None = None, **kwargs) -> Scene:
    """A scene from a built-in name or a file path.

    Args:
        source: a built-in name (``"cornell_box"``, ``"furnace"``) or a path to a ``.toml`` scene
            file, a Mitsuba 3 ``.xml`` scene file (the subset in :mod:`invrender.scene.formats.mitsuba`)
            or a ``.gltf``/``.glb``/``.obj``/``.ply``/``.stl`` mesh file (:mod:`invrender.scene.formats`).
        resolution: (width, height) in pixels; None = the scene's own.
        device: move the scene there (None = CPU).
        ambient: the Utah approximation's ambient radiance eps0 (RGB or one number, >= 0) stored in
            ``params["ambient.emission"]``; None = the scene's own (a TOML ``ambient`` key), if any.
        studio: mesh files only: place the mesh in the default studio (a camera framing it unless
            a glTF file has one, a floor and an area light: :mod:`invrender.scene.formats.studio`);
            None (default) = when the file has no emitter; False = the file as it is.
        kwargs: arguments of a built-in scene (e.g. ``rho=0.5, eps=1.0`` for ``furnace``).
    """
    source_str = str(source)
    is_mesh = source_str not in BUILTIN_SCENES and Path(source_str).suffix.lower() in formats.MESH_SUFFIXES
    if studio and not is_mesh:
        raise SceneError(f"{source_str}: studio applies to mesh files ({'/'.join(formats.MESH_SUFFIXES)}) only")
    if source_str in BUILTIN_SCENES:
        if resolution is not None:
            kwargs["resolution"] = resolution
        scene = builtin_scene(source_str, **kwargs)
    else:
        path = Path(source_str)
        if path.suffix.lower() not in formats.SUFFIXES:
            raise SceneError(f"unknown scene {source_str!r}{did_you_mean(source_str, BUILTIN_SCENES)}: not a built-in ({', '.join(BUILTIN_SCENES)}) nor a {'/'.join(formats.SUFFIXES)} file")
        if kwargs:
            raise SceneError(f"scene options {', '.join(kwargs)} apply to built-in scenes only")
        if not path.is_file():
            raise SceneError(f"scene file not found: {source_str}")
        scene = formats.load_mesh_file(path, resolution, studio=studio) if is_mesh else formats.load_file(path, resolution)
    if ambient is not None:
        scene = scene.with_ambient(ambient)
    return scene.to(device) if device is not None else scene


__all__ = ["Camera", "Mesh", "Scene", "build_scene", "load_scene", "BUILTIN_SCENES"]
