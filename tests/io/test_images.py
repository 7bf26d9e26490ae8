"""Image I/O: exact EXR round trips, sRGB PNG encoding, and one-line ImageErrors for every bad input."""

import os

import kornia
import numpy as np
import OpenEXR
import pytest
import torch
from PIL import Image

import invrender.io.images as images
from invrender.errors import ImageError
from invrender.io import read_image, write_image


def _hdr_image():
    g = torch.Generator().manual_seed(0)
    img = torch.rand(7, 5, 3, generator=g) * 100.0  # HDR values well above 1
    img[0, 0] = torch.tensor([1e-30, 1e-40, 3.4e38])  # tiny, subnormal and huge float32
    img[1, 1] = 0.0
    return img


def _leftovers(directory, keep):
    return sorted(p.name for p in directory.iterdir() if p.name not in keep)


def test_exr_round_trip_is_bit_exact(tmp_path):
    img = _hdr_image()
    write_image(tmp_path / "a.exr", img.requires_grad_())
    back = read_image(tmp_path / "a.exr")
    assert back.dtype == torch.float32 and back.shape == (7, 5, 3)
    assert torch.equal(back.view(torch.int32), img.detach().view(torch.int32))
    assert _leftovers(tmp_path, {"a.exr"}) == []


def test_exr_channels_are_r_g_b_float32_and_row0_is_top(tmp_path):
    img = torch.zeros(4, 3, 3)
    img[0, :, 0] = 1.0  # top row red
    write_image(tmp_path / "a.exr", img)
    with OpenEXR.File(str(tmp_path / "a.exr"), separate_channels=True) as f:
        ch = f.channels()
        assert sorted(ch) == ["B", "G", "R"]
        assert ch["R"].pixels.dtype == np.float32
        assert ch["R"].pixels[0].tolist() == [1.0, 1.0, 1.0] and ch["R"].pixels[1:].sum() == 0


def test_exr_y_only_is_replicated_and_alpha_dropped(tmp_path):
    y = np.arange(6, dtype=np.float32).reshape(2, 3)
    OpenEXR.File({}, {"Y": y}).write(str(tmp_path / "y.exr"))
    assert torch.equal(read_image(tmp_path / "y.exr"), torch.from_numpy(y)[..., None].expand(2, 3, 3))
    rgba = np.random.default_rng(0).random((2, 3, 4)).astype(np.float32)
    OpenEXR.File({}, {"RGBA": rgba}).write(str(tmp_path / "a.exr"))
    assert torch.equal(read_image(tmp_path / "a.exr"), torch.from_numpy(rgba[..., :3]))


def test_grey_image_is_written_as_rgb(tmp_path):
    write_image(tmp_path / "g.exr", torch.full((2, 2), 0.25))
    assert torch.equal(read_image(tmp_path / "g.exr"), torch.full((2, 2, 3), 0.25))


def test_png_round_trip_and_clipping(tmp_path):
    img = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(1))
    img[0, 0] = torch.tensor([5.0, 1.0, -0.5])  # clips to [0, 1]
    write_image(tmp_path / "a.png", img)
    back = read_image(tmp_path / "a.png", device="cpu")
    assert back.dtype == torch.float32 and back.shape == (16, 16, 3)
    assert torch.allclose(back[0, 0], torch.tensor([1.0, 1.0, 0.0]))
    # one 8-bit sRGB step is at most ~1/255 * d(linear)/d(srgb) <= 2.4/255 * 1.055 linear near white
    assert (back - img.clamp(0, 1)).abs().max() < 3.0 / 255


def test_png_srgb_encoding_of_half_is_188(tmp_path):
    write_image(tmp_path / "h.png", torch.full((1, 2, 3), 0.5))
    with Image.open(tmp_path / "h.png") as im:
        assert im.mode == "RGB"
        assert np.asarray(im).tolist() == [[[188, 188, 188]] * 2]


def test_jpeg_is_read_as_linear(tmp_path):
    Image.new("RGB", (3, 2), (255, 255, 255)).save(tmp_path / "w.jpg")
    assert torch.allclose(read_image(tmp_path / "w.jpg"), torch.ones(2, 3, 3))


def test_bmp_is_read_as_linear_srgb(tmp_path):
    """A BMP (Mitsuba's scenes use some, e.g. a projector's slide) decodes as a PNG of the same codes."""
    codes = np.array([[[255, 0, 10], [188, 188, 188]], [[0, 255, 128], [1, 2, 3]]], dtype=np.uint8)
    Image.fromarray(codes).save(tmp_path / "s.bmp")
    Image.fromarray(codes).save(tmp_path / "s.png")
    assert torch.equal(read_image(tmp_path / "s.bmp"), read_image(tmp_path / "s.png"))


@pytest.mark.parametrize("name", ["p.jpg", "p.JPEG"])
def test_jpeg_is_written_as_srgb_8_bit_at_its_quality(tmp_path, name):
    """A smooth linear ramp written as a camera stores it: sRGB codes (0.5 -> 188), JPEG-compressed;
    a higher quality gives a larger file closer to the image."""
    ramp = torch.linspace(0, 1, 64)
    img = torch.stack([ramp[None, :].expand(32, 64), ramp[:, None].expand(64, 64)[:32], torch.full((32, 64), 0.5)], -1)
    sizes, errors = [], []
    for quality in (30, 95):
        path = tmp_path / f"q{quality}" / name
        write_image(path, img, quality=quality)
        with Image.open(path) as im:
            assert im.format == "JPEG" and im.mode == "RGB" and im.size == (64, 32)
            codes = np.asarray(im).astype(int)
        assert abs(codes[..., 2].mean() - 188) < 1.5  # 0.5 linear is sRGB code 188
        sizes.append(path.stat().st_size)
        errors.append(float((read_image(path) - img).abs().mean()))
    assert sizes[1] > sizes[0] and errors[1] < errors[0] < 0.05
    assert errors[1] < 0.005


@pytest.mark.parametrize("quality", [0, 101, 9.5, True])
def test_jpeg_quality_out_of_range_raises(tmp_path, quality):
    with pytest.raises(ImageError, match=rf"a\.jpg.*quality must be an integer from 1 to 100, got {quality!r}"):
        write_image(tmp_path / "a.jpg", torch.ones(2, 2, 3), quality=quality)
    assert _leftovers(tmp_path, set()) == []


def test_missing_parent_directories_are_created(tmp_path):
    write_image(tmp_path / "runs" / "x" / "img.exr", torch.ones(2, 2, 3))
    assert (tmp_path / "runs" / "x" / "img.exr").is_file()


@pytest.mark.parametrize("content", [os.urandom(256), b"v/1\x01" + os.urandom(64)], ids=["random", "exr-magic"])
def test_corrupt_exr_raises(tmp_path, content):
    (tmp_path / "bad.exr").write_bytes(content)
    with pytest.raises(ImageError, match="bad.exr"):
        read_image(tmp_path / "bad.exr")


def test_truncated_exr_raises(tmp_path):
    write_image(tmp_path / "a.exr", torch.rand(64, 64, 3))
    data = (tmp_path / "a.exr").read_bytes()
    (tmp_path / "a.exr").write_bytes(data[: len(data) // 2])
    with pytest.raises(ImageError, match="a.exr"):
        read_image(tmp_path / "a.exr")


def test_corrupt_png_raises(tmp_path):
    (tmp_path / "bad.png").write_bytes(os.urandom(256))
    with pytest.raises(ImageError, match="bad.png"):
        read_image(tmp_path / "bad.png")


def test_missing_file_raises(tmp_path):
    with pytest.raises(ImageError, match="nope.exr.*not found"):
        read_image(tmp_path / "nope.exr")


@pytest.mark.parametrize("op", ["read", "write"])
def test_unknown_suffix_raises(tmp_path, op):
    (tmp_path / "a.tiff").write_bytes(b"x")
    with pytest.raises(ImageError, match=r"a\.tiff.*'\.tiff'.*\.exr"):
        read_image(tmp_path / "a.tiff") if op == "read" else write_image(tmp_path / "a.tiff", torch.ones(2, 2, 3))


@pytest.mark.parametrize("sub", ["img.exr", "deeper/img.png"])
def test_path_under_a_regular_file_raises(tmp_path, sub):
    (tmp_path / "file").write_text("x")
    with pytest.raises(ImageError, match="file"):
        write_image(tmp_path / "file" / sub, torch.ones(2, 2, 3))
    assert (tmp_path / "file").read_text() == "x"
    assert _leftovers(tmp_path, {"file"}) == []


def test_target_is_a_directory_raises_and_leaves_nothing(tmp_path):
    (tmp_path / "d.exr").mkdir()
    with pytest.raises(ImageError, match="d.exr"):
        write_image(tmp_path / "d.exr", torch.ones(2, 2, 3))
    assert _leftovers(tmp_path, {"d.exr"}) == [] and list((tmp_path / "d.exr").iterdir()) == []


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root ignores directory permissions")
def test_read_only_directory_raises(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    try:
        with pytest.raises(ImageError, match="ro.*Permission denied"):
            write_image(ro / "a.exr", torch.ones(2, 2, 3))
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


@pytest.mark.parametrize("name,writer", [("t.exr", "_write_exr"), ("t.png", "_write_srgb8"), ("t.jpg", "_write_srgb8")])
def test_failing_write_leaves_existing_target_untouched(tmp_path, monkeypatch, name, writer):
    target = tmp_path / name
    target.write_bytes(b"precious")

    def fail(f, rgb, *args):
        f.write(b"partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(images, writer, fail)
    with pytest.raises(ImageError, match=f"{name}.*No space left"):
        write_image(target, torch.ones(2, 2, 3))
    assert target.read_bytes() == b"precious"
    assert _leftovers(tmp_path, {name}) == []


@pytest.mark.parametrize("shape", [(2, 2, 4), (2, 2, 1), (3, 2, 2, 3), (3,), (0, 2, 3)])
def test_wrong_shape_raises(tmp_path, shape):
    with pytest.raises(ImageError, match=r"a\.exr.*\(H, W, 3\)"):
        write_image(tmp_path / "a.exr", torch.ones(shape))
    assert _leftovers(tmp_path, set()) == []


@pytest.mark.parametrize("name", ["a.exr", "a.png"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_nan_or_inf_raises_and_keeps_target(tmp_path, name, bad):
    target = tmp_path / name
    target.write_bytes(b"precious")
    img = torch.ones(2, 2, 3)
    img[1, 0, 2] = bad
    with pytest.raises(ImageError, match="NaN/Inf"):
        write_image(target, img)
    assert target.read_bytes() == b"precious"
    assert _leftovers(tmp_path, {name}) == []


def test_read_photo_keeps_codes_bit_depth_and_alpha(tmp_path):
    """read_photo: 16-bit RGBA and 8-bit grey PNGs (OpenCV), JPEG (PIL), EXR; codes / top code,
    the bit depth, the alpha channel and the default response."""
    import cv2

    from invrender.io.images import read_mask, read_photo, write_photo

    rng = np.random.default_rng(0)
    rgba = rng.integers(0, 65536, size=(5, 7, 4), dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "a16.png"), rgba[..., [2, 1, 0, 3]])  # OpenCV writes BGRA
    photo = read_photo(tmp_path / "a16.png")
    assert photo.bits == 16 and photo.top_code == 65535 and photo.default_response == "srgb"
    np.testing.assert_array_equal(np.round(photo.values.numpy() * 65535).astype(np.uint16), rgba[..., :3])
    np.testing.assert_allclose(photo.alpha.numpy(), rgba[..., 3] / 65535.0, rtol=1e-6)
    torch.testing.assert_close(read_mask(tmp_path / "a16.png"), photo.alpha)
    grey = rng.integers(0, 256, size=(4, 3), dtype=np.uint8)
    Image.fromarray(grey, mode="L").save(tmp_path / "g.png")
    photo = read_photo(tmp_path / "g.png")
    assert photo.bits == 8 and photo.alpha is None
    np.testing.assert_array_equal(np.round(photo.values.numpy() * 255).astype(np.uint8), np.repeat(grey[..., None], 3, -1))
    values = torch.rand(8, 8, 3)
    write_photo(tmp_path / "p16.png", values, bits=16)
    assert float((read_photo(tmp_path / "p16.png").values - values).abs().max()) <= 0.5 / 65535 + 1e-7
    write_photo(tmp_path / "p.jpg", values, quality=100)
    photo = read_photo(tmp_path / "p.jpg")
    assert photo.bits == 8 and float((photo.values - values).abs().max()) < 0.05
    write_image(tmp_path / "f.exr", values * 4)
    photo = read_photo(tmp_path / "f.exr")
    assert photo.bits is None and photo.default_response == "linear"
    torch.testing.assert_close(photo.values, values * 4)
    with pytest.raises(ImageError, match="p.gif"):
        read_photo(tmp_path / "p.gif")
    with pytest.raises(ImageError, match="16-bit .png"):
        write_photo(tmp_path / "x.jpg", values, bits=16)


def _bad_filter_png(path):
    """A PNG whose signature and header are valid but whose pixel rows are not (libpng complains on
    stderr itself: 'libpng error: bad adaptive filter value')."""
    write_image(path, torch.rand(16, 16, 3))
    data = bytearray(path.read_bytes())
    for i in range(len(data) // 2, len(data) - 20):
        data[i] ^= 0x5A
    path.write_bytes(bytes(data))


def _truncated_exr(path):
    """An EXR cut in half: OpenEXR's C core and its binding each print a line of their own."""
    write_image(path, torch.rand(64, 64, 3))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


@pytest.mark.parametrize("make, name, reason", [(_truncated_exr, "cut.exr", "corrupt or truncated EXR pixel data"), (_bad_filter_png, "rows.png", "not a valid PNG file")])
def test_native_libraries_print_nothing_their_words_end_up_in_the_error(tmp_path, capfd, make, name, reason):
    """OpenEXR's and libpng's own lines on descriptor 2 are caught (capfd sees the descriptor, not
    only sys.stderr): the one-line ImageError names the file and folds in the library's reason;
    read_photo (OpenCV) and read_image (PIL / OpenEXR) alike."""
    from invrender.io.images import read_photo

    make(tmp_path / name)
    for read in (read_image, read_photo):
        with pytest.raises(ImageError) as error:
            read(tmp_path / name)
        message = str(error.value)
        assert message.startswith(f"cannot read image {tmp_path / name}: {reason}") and "\n" not in message, message
        assert capfd.readouterr() == ("", "")


def test_native_output_restores_descriptor_2_after_an_error(capfd):
    from invrender.io.native import native_output

    with pytest.raises(RuntimeError):
        with native_output() as printed:
            os.write(2, b"a library's complaint\n")
            raise RuntimeError("the read failed")
    assert printed == ["a library's complaint"]
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"


def test_a_16_bit_png_is_read_at_16_bits(tmp_path):
    """read_image of a 16-bit RGB PNG keeps every code (PIL alone would give 8 bits)."""
    import cv2

    codes = np.arange(4 * 5 * 3, dtype=np.uint16).reshape(4, 5, 3) * 1000 + 7
    cv2.imwrite(str(tmp_path / "deep.png"), codes[..., ::-1])
    expected = kornia.color.rgb_to_linear_rgb(torch.from_numpy(codes / 65535.0).permute(2, 0, 1)).permute(1, 2, 0)
    torch.testing.assert_close(read_image(tmp_path / "deep.png").double(), expected, atol=1e-6, rtol=0)


@pytest.mark.parametrize("make, name", [(_truncated_exr, "cut.exr"), (_bad_filter_png, "rows.png")])
def test_cli_a_corrupt_target_is_one_line_naming_it(tmp_path, make, name):
    """``invrender fit --target`` a corrupt EXR or PNG: exit 2, one line naming the file (no
    OpenEXR or libpng line before it), no output folder."""
    from tests.conftest import refused

    make(tmp_path / name)
    line = refused(tmp_path, "fit", "--scene", "cornell_box", "--target", str(tmp_path / name), "--params", "red.reflectance", "--resolution", "16x16")
    assert line.startswith(f"invrender: error: cannot read image {tmp_path / name}: ")
