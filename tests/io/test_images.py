"""Image files: exact EXR round trips, sRGB PNGs, one-line errors, atomic writes."""

import numpy as np
import pytest
import torch
from PIL import Image

import invrender as ir
from invrender.errors import ImageError


def test_exr_round_trip_is_bit_exact(tmp_path):
    img = torch.rand(9, 13, 3) * 100
    img[0, 0] = torch.tensor([1e-30, 65504.0 * 8, 0.0])  # beyond half range: stored as float32
    ir.write_image(tmp_path / "a.exr", img)
    assert torch.equal(ir.read_image(tmp_path / "a.exr"), img)


def test_png_is_srgb_encoded_and_clipped(tmp_path):
    img = torch.tensor([[[0.5, 0.0, 1.0], [2.0, 0.0031308, 0.214]]])
    ir.write_image(tmp_path / "a.png", img)
    raw = np.asarray(Image.open(tmp_path / "a.png"))
    assert raw[0, 0].tolist() == [188, 0, 255]  # sRGB(0.5) = 0.7354 -> 188
    assert raw[0, 1, 0] == 255  # > 1 clips
    back = ir.read_image(tmp_path / "a.png")
    assert torch.allclose(back, img.clamp(0, 1), atol=0.01)


def test_grey_image_written_as_rgb(tmp_path):
    ir.write_image(tmp_path / "g.exr", torch.ones(3, 4) * 0.25)
    assert torch.equal(ir.read_image(tmp_path / "g.exr"), torch.full((3, 4, 3), 0.25))


@pytest.mark.parametrize("name, content, words", [("bad.exr", b"not an exr" * 20, "not a valid EXR"), ("bad.png", b"\x89PNG broken", "not a valid PNG")])
def test_corrupt_files(tmp_path, name, content, words):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(ImageError, match=words) as e:
        ir.read_image(tmp_path / name)
    assert "\n" not in str(e.value)


def test_missing_and_unknown_suffix(tmp_path):
    with pytest.raises(ImageError, match="not found"):
        ir.read_image(tmp_path / "nope.exr")
    with pytest.raises(ImageError, match="unknown image suffix"):
        ir.read_image(tmp_path / "x.tiff")
    with pytest.raises(ImageError, match="unknown image suffix"):
        ir.write_image(tmp_path / "x.bmp", torch.zeros(2, 2, 3))


def test_bad_images_and_unwritable_paths_leave_nothing(tmp_path):
    target = tmp_path / "keep.exr"
    good = torch.ones(2, 2, 3)
    ir.write_image(target, good)
    with pytest.raises(ImageError, match="NaN"):
        ir.write_image(target, torch.full((2, 2, 3), float("nan")))
    with pytest.raises(ImageError, match=r"shape \(H, W, 3\)"):
        ir.write_image(target, torch.zeros(2, 2, 4))
    assert torch.equal(ir.read_image(target), good)  # the existing file is untouched
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ImageError, match="cannot write"):
        ir.write_image(blocker / "img.png", good)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "keep.exr"]  # no temporary left behind
