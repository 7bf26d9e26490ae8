"""Input and output, the layer below the scene: linear-radiance images to and from EXR, PNG and JPEG
files (:mod:`~invrender.io.images`), atomic file writes (:mod:`~invrender.io.atomic`), which process
of a torch.distributed group writes (:mod:`~invrender.io.ranks`) and the writers of reports: text,
JSON, figures (:mod:`~invrender.io.reports`).

:func:`read_image` and :func:`write_image` are imported on first use: the image codecs (kornia,
OpenEXR, Pillow: about 2 s and 25 MiB) stay out of a process that only renders to tensors, which
reaches this package through :mod:`~invrender.io.ranks`.
"""

__all__ = ["read_image", "write_image"]


def __getattr__(name: str):
    if name in __all__:
        from invrender.io import images

        return getattr(images, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
