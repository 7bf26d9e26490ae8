"""Read and write images as linear-radiance torch tensors.

Every image in invrender is a float tensor of shape (H, W, 3): linear RGB radiance (W sr^-1 m^-2 per
channel, unitless scale), row 0 at the top. EXR files hold those values exactly (float32); PNG and
JPEG files hold sRGB-encoded values in [0, 1] (8 bits; a PNG read may have 16, every code kept) and
are converted to and from linear on the way (written as a camera would store them: :func:`write_image`'s
``quality``).
Radiance ``.hdr`` (RGBE) files are read as linear (through OpenCV), for environment maps.
:func:`read_photo` reads a file as a camera stored it (a fit target that is a photograph): its
encoded values, bit depth, default camera response and alpha channel (:class:`Photo`), 8- and
16-bit PNG (grey or RGB, with or without alpha, through OpenCV), JPEG, EXR and HDR.
Every failure raises :class:`~invrender.errors.ImageError` with a one-line message naming the file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import kornia
import numpy as np
import OpenEXR
import torch
from PIL import Image

from invrender.errors import ImageError
from invrender.io.atomic import atomic_file
from invrender.io.native import last_line, native_output

WRITE_SUFFIXES = (".exr", ".png", ".jpg", ".jpeg")
READ_SUFFIXES = (".exr", ".hdr", ".png", ".jpg", ".jpeg", ".bmp")


def write_image(path: str | os.PathLike, image: torch.Tensor, quality: int = 95) -> None:
    """Write a linear-radiance image to ``path``, atomically.

    Args:
        path: target file; ``.exr`` stores float32 R, G, B channels exactly, ``.png`` stores the
            image sRGB-encoded, clipped to [0, 1], 8 bits per channel, and ``.jpg``/``.jpeg`` the
            same 8-bit sRGB values JPEG-compressed, as a camera stores a photograph (Pillow's
            encoder, no chroma subsampling). Missing parent directories are created.
        image: (H, W, 3) or (H, W) float tensor of linear radiance, row 0 at the top, on any device;
            gradients are ignored. A (H, W) image is written as grey.
        quality: JPEG quality, 1 (smallest file) to 100 (Pillow's scale); other formats ignore it.
            For a camera's exposure, white balance and response applied first, see
            :func:`invrender.inverse.sensor.photograph` and :func:`write_photo`.

    The image goes to a temporary file in the target's directory which then replaces the target, so a
    failed write leaves any existing target untouched and no partial file behind.

    Raises:
        ImageError: unknown suffix, wrong shape, NaN/Inf values, or the path cannot be written.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITE_SUFFIXES:
        raise ImageError(f"cannot write image {path}: unknown suffix {suffix!r}, expected one of {', '.join(WRITE_SUFFIXES)}")
    if isinstance(quality, bool) or not isinstance(quality, int) or not 1 <= quality <= 100:
        raise ImageError(f"cannot write image {path}: quality must be an integer from 1 to 100, got {quality!r}")
    rgb = _to_rgb_array(image, path)

    parent = path.parent
    if parent.exists() and not parent.is_dir():
        raise ImageError(f"cannot write image {path}: {parent} is not a directory")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ImageError(f"cannot write image {path}: cannot create directory {parent}: {e.strerror or e}") from None
    try:
        with atomic_file(path) as f:
            if suffix == ".exr":
                _write_exr(f, rgb)
            else:
                _write_srgb8(f, rgb, "PNG" if suffix == ".png" else "JPEG", quality)
    except Exception as e:  # OSError, or OpenEXR's RuntimeError; atomic_file left no temporary file
        raise ImageError(f"cannot write image {path}: {_reason(e)}") from None


def read_image(path: str | os.PathLike, device: torch.device | str | None = None, raw: bool = False) -> torch.Tensor:
    """Read an image file as linear radiance.

    Args:
        path: ``.exr`` (R, G, B channels; a Y-only file is replicated to grey, alpha is dropped),
            ``.hdr`` (Radiance RGBE, linear), or
            ``.png`` (8 or 16 bits) / ``.jpg`` / ``.jpeg`` / ``.bmp`` (decoded from sRGB to linear,
            as Mitsuba reads them; alpha dropped).
        device: device of the returned tensor (default CPU).
        raw: PNG and JPEG values as stored (codes over their largest), not decoded from sRGB
            (Mitsuba's bitmap ``raw``: normal maps, height maps).

    Returns:
        (H, W, 3) float32 tensor of linear RGB, row 0 at the top.

    Raises:
        ImageError: the file is missing, has an unknown suffix, or cannot be decoded.
    """
    path, suffix = _readable(path)
    try:
        rgb = _read_exr(path) if suffix == ".exr" else _read_hdr(path) if suffix == ".hdr" else _read_srgb(path, raw)
    except ImageError:
        raise
    except Exception as e:  # OpenEXR raises RuntimeError/ValueError, PIL OSError/SyntaxError/...
        raise ImageError(f"cannot read image {path}: not a valid {suffix[1:].upper()} file ({_reason(e)})") from None
    return rgb.to(device) if device is not None else rgb


def _readable(path) -> tuple[Path, str]:
    """``(path, its lower-case suffix)``; an :class:`ImageError` naming the file when the suffix is
    not one :func:`read_image` reads or the file is missing or not a regular file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READ_SUFFIXES:
        raise ImageError(f"cannot read image {path}: unknown suffix {suffix!r}, expected one of {', '.join(READ_SUFFIXES)}")
    if not path.exists():
        raise ImageError(f"cannot read image {path}: file not found")
    if not path.is_file():
        raise ImageError(f"cannot read image {path}: not a regular file")
    return path, suffix


def _reason(e: Exception) -> str:
    """The OS reason (``strerror``) or the first line of an exception's message, for a one-line error."""
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    lines = str(e).strip().splitlines()
    return lines[0] if lines else type(e).__name__


def _to_rgb_array(image, path: Path) -> np.ndarray:
    """Validate ``image`` and return it as a C-contiguous float32 (H, W, 3) numpy array."""
    image = torch.as_tensor(image).detach()
    if image.ndim == 2:
        image = image[..., None].expand(-1, -1, 3)
    if image.ndim != 3 or image.shape[-1] != 3 or image.shape[0] == 0 or image.shape[1] == 0:
        raise ImageError(f"cannot write image {path}: expected shape (H, W, 3) or (H, W), got {tuple(image.shape)}")
    if not image.is_floating_point():
        raise ImageError(f"cannot write image {path}: expected a float image, got dtype {image.dtype}")
    if not torch.isfinite(image).all():
        raise ImageError(f"cannot write image {path}: image contains NaN/Inf")
    return np.ascontiguousarray(image.to("cpu", torch.float32).numpy())


def _write_exr(f, rgb: np.ndarray) -> None:
    """Write (H, W, 3) float32 ``rgb`` to the binary file ``f`` as lossless float32 R, G, B channels."""
    channels = {name: np.ascontiguousarray(rgb[..., i]) for i, name in enumerate("RGB")}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(f)


def to_srgb(image: torch.Tensor) -> torch.Tensor:
    """(H, W, 3) linear radiance -> (H, W, 3) sRGB-encoded display values, clipped to [0, 1]."""
    linear = torch.as_tensor(image).detach().float().cpu().clamp(0.0, 1.0).permute(2, 0, 1)
    return kornia.color.linear_rgb_to_rgb(linear).clamp(0.0, 1.0).permute(1, 2, 0)


def _write_srgb8(f, rgb: np.ndarray, format: str, quality: int) -> None:
    """Write (H, W, 3) linear ``rgb`` to the binary file ``f`` as 8-bit sRGB codes, ``format``
    ``"PNG"`` or ``"JPEG"`` (at ``quality``, chroma not subsampled: 4:4:4)."""
    srgb = to_srgb(torch.from_numpy(rgb)).numpy()
    codes = Image.fromarray(np.round(srgb * 255.0).astype(np.uint8), mode="RGB")
    codes.save(f, format=format, **({"quality": quality, "subsampling": "4:4:4"} if format == "JPEG" else {}))


def _read_exr(path: Path) -> torch.Tensor:
    """Read an EXR file's first part as a (H, W, 3) float32 tensor."""
    # On bad pixel data (e.g. a truncated file) OpenEXR's C core writes a line to descriptor 2 and its
    # binding a "Warning: ..." line to sys.stdout, and it returns a File with no parts: both lines
    # are caught, the last becomes the error's reason.
    with native_output() as printed:
        try:
            with OpenEXR.File(str(path), separate_channels=True) as f:
                channels = {name: c.pixels for name, c in f.channels().items()} if f.parts else None
        except Exception as e:
            error = e
        else:
            error = None
    if error is not None:
        raise ImageError(f"cannot read image {path}: not a valid EXR file ({last_line(printed, _reason(error))})")
    if channels is None:
        raise ImageError(f"cannot read image {path}: corrupt or truncated EXR pixel data ({last_line(printed, 'no readable parts')})")
    if all(c in channels for c in "RGB"):
        planes = [channels[c] for c in "RGB"]
    elif "Y" in channels:
        planes = [channels["Y"]] * 3
    else:
        raise ImageError(f"cannot read image {path}: no R, G, B or Y channels (found {', '.join(sorted(channels)) or 'none'})")
    rgb = np.stack([np.asarray(p, dtype=np.float32) for p in planes], axis=-1)
    return torch.from_numpy(rgb)


def _cv2_read(path: Path, flags: int, what: str) -> np.ndarray:
    """``cv2.imread(path, flags)`` with OpenCV's logger silenced and what libpng prints caught:
    the array, or an :class:`ImageError` naming the file, with libpng's last word if it had one."""
    import cv2  # lazily: only .hdr files and photographs read as codes need it

    log = cv2.utils.logging
    level = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)  # OpenCV's own logger: its long lines say no more than ours
    try:
        with native_output() as printed:  # what libpng prints itself ("libpng error: ...")
            data = cv2.imread(str(path), flags)
    finally:
        log.setLogLevel(level)
    if data is None:
        raise ImageError(f"cannot read image {path}: not a valid {what} file" + (f" ({printed[-1]})" if printed else ""))
    return data


def _read_hdr(path: Path) -> torch.Tensor:
    """Read a Radiance RGBE (.hdr) file as a (H, W, 3) float32 linear tensor (OpenCV's reader, which
    gives BGR)."""
    import cv2

    bgr = _cv2_read(path, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_COLOR, "HDR (Radiance RGBE)")
    if bgr is None or bgr.ndim != 3 or bgr.shape[2] != 3:
        raise ImageError(f"cannot read image {path}: not a valid HDR (Radiance RGBE) file")
    return torch.from_numpy(np.ascontiguousarray(bgr[..., ::-1], dtype=np.float32))


def _read_srgb(path: Path, raw: bool = False) -> torch.Tensor:
    """Read a PNG (8 or 16 bits, every code kept: OpenCV's reader), a JPEG or a BMP as a (H, W, 3)
    float32 linear tensor (``raw``: the codes as they are, not decoded)."""
    if path.suffix.lower() == ".png":
        codes = _read_png_codes(path).values
        return codes.contiguous() if raw else kornia.color.rgb_to_linear_rgb(codes.permute(2, 0, 1)).permute(1, 2, 0).contiguous()
    with Image.open(path) as img:
        img.load()
        if raw:
            return torch.from_numpy(np.asarray(img.convert("RGB"), dtype=np.float32) / 255.0).contiguous()
        return decode_srgb(img)


def decode_srgb(img: Image.Image) -> torch.Tensor:
    """An sRGB-encoded PIL image (8 bits per channel, or 16-bit grey) -> (H, W, 3) float32 linear
    tensor, row 0 at the top; alpha dropped, grey replicated."""
    linear = kornia.color.rgb_to_linear_rgb(image_codes(img).permute(2, 0, 1))
    return linear.permute(1, 2, 0).contiguous()


def image_codes(img: Image.Image) -> torch.Tensor:
    """A PIL image's values as stored (8 bits per channel, or 16-bit grey), not decoded: (H, W, 3)
    float32 codes over the top code, row 0 at the top; alpha dropped, grey replicated. What a
    texture holding data rather than colour is (normal maps, glTF's metallic-roughness texture)."""
    if img.mode.startswith("I;16"):
        grey = np.asarray(img, dtype=np.float32) / 65535.0
        return torch.from_numpy(np.ascontiguousarray(np.repeat(grey[..., None], 3, axis=-1)))
    return torch.from_numpy(np.asarray(img.convert("RGB"), dtype=np.float32) / 255.0).contiguous()


@dataclass(frozen=True)
class Photo:
    """An image file as the camera stored it.

    Attributes:
        path: the file.
        values: (H, W, 3) float32 encoded values: code / top code in [0, 1] for an integer file,
            the stored floats for EXR and HDR; grey replicated to RGB; row 0 at the top.
        bits: bits per channel of an integer file (8 or 16), None for a float file.
        alpha: (H, W) float32 alpha in [0, 1] when the file has an alpha channel, else None.
    """

    path: Path
    values: torch.Tensor
    bits: int | None
    alpha: torch.Tensor | None

    @property
    def default_response(self) -> str:
        """``"srgb"`` for an 8- or 16-bit file, ``"linear"`` for a float one."""
        return "linear" if self.bits is None else "srgb"

    @property
    def top_code(self) -> int | None:
        """The largest code of an integer file (255, 65535), None for a float one."""
        return None if self.bits is None else 2**self.bits - 1


def read_photo(path: str | os.PathLike) -> Photo:
    """Read ``path`` (``.png``, ``.jpg``/``.jpeg``, ``.exr``, ``.hdr``) without converting it:
    a :class:`Photo` with its encoded values, bit depth and alpha. Raises :class:`ImageError` naming
    the file when it is missing, of an unknown suffix, or cannot be decoded."""
    path, suffix = _readable(path)
    try:
        if suffix == ".exr":
            return Photo(path, _read_exr(path), None, None)
        if suffix == ".hdr":
            return Photo(path, _read_hdr(path), None, None)
        if suffix == ".png":
            return _read_png_codes(path)
        with Image.open(path) as img:
            img.load()
            if img.mode.startswith("I;16"):
                grey = np.asarray(img, dtype=np.float32) / 65535.0
                return Photo(path, torch.from_numpy(np.repeat(grey[..., None], 3, axis=-1)), 16, None)
            alpha = np.asarray(img.getchannel("A"), dtype=np.float32) / 255.0 if "A" in img.getbands() else None
            rgb = np.asarray(img.convert("RGB"), dtype=np.float32) / 255.0
        return Photo(path, torch.from_numpy(rgb), 8, None if alpha is None else torch.from_numpy(alpha))
    except ImageError:
        raise
    except Exception as e:
        raise ImageError(f"cannot read image {path}: not a valid {suffix[1:].upper()} file ({_reason(e)})") from None


def _read_png_codes(path: Path) -> Photo:
    """A PNG's codes through OpenCV (8 or 16 bits, grey, grey + alpha, RGB or RGBA)."""
    import cv2

    data = _cv2_read(path, cv2.IMREAD_UNCHANGED, "PNG")
    if data.dtype not in (np.uint8, np.uint16):
        raise ImageError(f"cannot read image {path}: expected 8 or 16 bits per channel, got {data.dtype}")
    bits = 8 if data.dtype == np.uint8 else 16
    codes = data.astype(np.float32) / float(2**bits - 1)
    if codes.ndim == 2:
        codes = codes[..., None]
    alpha = None
    if codes.shape[2] in (2, 4):  # grey + alpha or BGRA
        alpha = torch.from_numpy(np.ascontiguousarray(codes[..., -1]))
        codes = codes[..., :-1]
    rgb = np.repeat(codes, 3, axis=-1) if codes.shape[2] == 1 else codes[..., ::-1]
    return Photo(path, torch.from_numpy(np.ascontiguousarray(rgb)), bits, alpha)


def read_mask(path: str | os.PathLike) -> torch.Tensor:
    """A per-pixel weight image (H, W) in [0, 1] from ``path``: its alpha channel when it has one,
    else the mean of its channels' encoded values (a black-and-white or grey mask image: white
    counts, black does not), clamped to [0, 1]."""
    photo = read_photo(path)
    weights = photo.alpha if photo.alpha is not None else photo.values.mean(-1)
    return weights.clamp(0.0, 1.0)


def write_photo(path: str | os.PathLike, encoded: torch.Tensor, bits: int = 8, quality: int = 95, subsampling: str = "4:4:4") -> None:
    """Write (H, W, 3) encoded values in [0, 1] (a camera's output, e.g.
    :func:`invrender.inverse.sensor.photograph`) quantized to ``bits`` per channel, atomically:
    ``.jpg``/``.jpeg`` (8 bits; JPEG ``quality`` and chroma ``subsampling``, PIL's names) or
    ``.png`` (8 or 16 bits). The values are written as they are (no response is applied)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".jpg", ".jpeg") or bits not in (8, 16) or (bits == 16 and suffix != ".png"):
        raise ImageError(f"cannot write photo {path}: 8-bit .jpg/.png or 16-bit .png, got {bits} bits and suffix {suffix!r}")
    values = _to_rgb_array(encoded, path)
    if values.min() < 0 or values.max() > 1:
        raise ImageError(f"cannot write photo {path}: encoded values must lie in [0, 1]")
    top = 2**bits - 1
    codes = np.round(values * top).astype(np.uint8 if bits == 8 else np.uint16)
    try:
        with atomic_file(path) as f:
            if bits == 16:
                import cv2

                ok, data = cv2.imencode(".png", np.ascontiguousarray(codes[..., ::-1]))
                if not ok:
                    raise ImageError(f"cannot write photo {path}: OpenCV could not encode it")
                f.write(data.tobytes())
            elif suffix == ".png":
                Image.fromarray(codes, mode="RGB").save(f, format="PNG")
            else:
                Image.fromarray(codes, mode="RGB").save(f, format="JPEG", quality=quality, subsampling=subsampling)
    except ImageError:
        raise
    except Exception as e:
        raise ImageError(f"cannot write photo {path}: {_reason(e)}") from None
