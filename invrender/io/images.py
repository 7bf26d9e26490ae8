"""Reading and writing images: OpenEXR (linear float32 RGB) and PNG (sRGB-encoded, 8-bit).

Images are torch tensors (H, W, 3) of linear radiance with row 0 at the top. Writes are atomic
(temporary file in the target's folder, then ``os.replace``), so a failure never leaves a partial
file and never damages an existing one.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import torch

from invrender.errors import ImageError

SUFFIXES = (".exr", ".png")
READ_SUFFIXES = (".exr", ".png", ".jpg", ".jpeg")


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear values in [0, 1] -> sRGB-encoded values in [0, 1] (IEC 61966-2-1)."""
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(np.maximum(linear, 0.0031308), 1 / 2.4) - 0.055)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear values in [0, 1]."""
    return np.where(encoded <= 0.04045, encoded / 12.92, np.power((encoded + 0.055) / 1.055, 2.4))


def write_image(path, image: torch.Tensor) -> None:
    """Write ``image`` (H, W, 3) or (H, W), linear radiance, to ``.exr`` (float32) or ``.png`` (sRGB).

    Raises:
        ImageError: unknown suffix, wrong shape, NaN/Inf values, or a path that cannot be written.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ImageError(f"cannot write {path}: unknown image suffix {path.suffix or '(none)'!r} (use {', '.join(SUFFIXES)})")
    rgb = _as_rgb(image, path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{suffix}", dir=path.parent)
        os.close(fd)
    except OSError as e:
        raise ImageError(f"cannot write {path}: {e.strerror or e}") from None
    try:
        if suffix == ".exr":
            _write_exr(tmp, rgb)
        else:
            _write_png(tmp, rgb)
        os.replace(tmp, path)
    except Exception as e:
        Path(tmp).unlink(missing_ok=True)
        reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        raise ImageError(f"cannot write {path}: {reason}") from None


def read_image(path, device=None) -> torch.Tensor:
    """Read an image as float32 linear RGB (H, W, 3): EXR as stored, PNG/JPEG decoded from sRGB.

    Raises:
        ImageError: missing, unreadable or corrupt file, or an unknown suffix.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READ_SUFFIXES:
        raise ImageError(f"cannot read {path}: unknown image suffix {path.suffix or '(none)'!r} (use {', '.join(READ_SUFFIXES)})")
    if not path.is_file():
        raise ImageError(f"image file not found: {path}")
    try:
        rgb = _read_exr(path) if suffix == ".exr" else _read_8bit(path)
    except ImageError:
        raise
    except Exception as e:
        raise ImageError(f"cannot read {path}: not a valid {suffix[1:].upper()} file ({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None
    return torch.from_numpy(np.ascontiguousarray(rgb, dtype=np.float32)).to(device or "cpu")


def _as_rgb(image, path: Path) -> np.ndarray:
    if not isinstance(image, torch.Tensor):
        image = torch.as_tensor(np.asarray(image))
    a = image.detach().to("cpu", torch.float32)
    if a.ndim == 2:
        a = a[..., None].expand(-1, -1, 3)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ImageError(f"cannot write {path}: expected an image of shape (H, W, 3), got {tuple(image.shape)}")
    if not torch.isfinite(a).all():
        raise ImageError(f"cannot write {path}: the image contains NaN or Inf values")
    return a.contiguous().numpy()


def _write_exr(path: str, rgb: np.ndarray) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {"RGB": np.ascontiguousarray(rgb, dtype=np.float32)}
    with OpenEXR.File(header, channels) as f:
        f.write(path)


def _write_png(path: str, rgb: np.ndarray) -> None:
    from PIL import Image

    encoded = srgb_encode(np.clip(rgb, 0.0, 1.0))
    Image.fromarray(np.round(encoded * 255.0).astype(np.uint8), mode="RGB").save(path, format="PNG")


def _read_exr(path: Path) -> np.ndarray:
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        names = {k.split(".")[-1]: np.array(v.pixels) for k, v in f.channels().items()}
    if all(c in names for c in "RGB"):
        return np.stack([names[c] for c in "RGB"], axis=-1).astype(np.float32)
    if "Y" in names:
        return np.repeat(names["Y"][..., None], 3, axis=-1).astype(np.float32)
    raise ImageError(f"cannot read {path}: no R, G, B (or Y) channels, found {', '.join(sorted(names)) or 'none'}")


def _read_8bit(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        im.load()
        bits = 16 if im.mode in ("I;16", "I;16B", "I") else 8
        rgb = np.asarray(im.convert("RGB") if bits == 8 else im, dtype=np.float64)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=-1)
    return srgb_decode(rgb / (2**bits - 1)).astype(np.float32)
