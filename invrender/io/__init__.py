"""Image input and output: linear-radiance tensors to and from EXR, PNG and JPEG files."""

from invrender.io.images import read_image, write_image

__all__ = ["read_image", "write_image"]
