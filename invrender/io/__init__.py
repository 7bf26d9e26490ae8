"""Image input and output (OpenEXR, PNG)."""

from invrender.io.images import read_image, write_image

__all__ = ["read_image", "write_image"]
