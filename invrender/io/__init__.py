"""Input and output, the layer below the scene: linear-radiance images to and from EXR, PNG and JPEG
files (:mod:`~invrender.io.images`), atomic file writes (:mod:`~invrender.io.atomic`), which process
of a torch.distributed group writes (:mod:`~invrender.io.ranks`) and the writers of reports: text,
JSON, figures (:mod:`~invrender.io.reports`)."""

from invrender.io.images import read_image, write_image

__all__ = ["read_image", "write_image"]
