"""HDR from an exposure bracket (invrender.io.hdr, ``invrender hdr``): a synthetic bracket, one linear
image through a known camera response at four exposures quantized to 8 bits, is merged back to the
linear image; the response CSV's format; the command end to end; one-line errors for bad input."""

import io

import numpy as np
import pytest
import torch
from PIL import ExifTags, Image
from PIL.TiffImagePlugin import IFDRational

from invrender.cli import main
from invrender.errors import ImageError, ParameterError
from invrender.io import read_image
from invrender.io.hdr import CSV_HEADER, merge_bracket, merge_images, response_csv, write_response_csv

TIMES = np.array([1 / 8, 1 / 2, 2.0, 8.0])


def srgb(v):
    """The sRGB encoding of linear v in [0, 1]."""
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(np.maximum(v, 0.0031308), 1 / 2.4) - 0.055)


def film(v):
    """A response with a strong shoulder (a film-like roll-off), v in [0, 1] -> [0, 1]."""
    return (1 - np.exp(-3 * v)) / (1 - np.exp(-3))


def radiance(h=32, w=48):
    """(h, w, 3) linear radiance: log-uniform from 0.01 to 6 left to right, a different tint per
    channel down the rows, and a 'lamp' of 20 in the top-left corner (clipped in every exposure)."""
    x = np.linspace(0, 1, w)[None, :, None]
    y = np.linspace(0, 1, h)[:, None, None]
    tint = np.concatenate([0.55 + 0.45 * y, 1 - 0.45 * y, 0.75 + 0 * y], axis=-1)
    e = np.exp(np.log(0.01) * (1 - x) + np.log(6.0) * x) * tint
    e[:6, :6] = 20.0
    return e


def photograph(e, t, response=srgb):
    """What an 8-bit camera with ``response`` (clipping at E t = 1) records at exposure time t."""
    return np.round(255 * response(np.clip(e * t, 0, 1))).astype(np.uint8)


def errors(hdr, e, unclipped):
    """The per-channel scale (geometric mean of merged / truth) and the relative errors after it."""
    ratio = hdr.numpy().astype(np.float64)[unclipped] / e[unclipped]
    scale = np.exp(np.log(ratio).mean(axis=0))
    return scale, np.abs(ratio / scale - 1)


def test_synthetic_srgb_bracket_recovers_the_linear_image_within_2_percent():
    e = radiance()
    images = [photograph(e, t) for t in TIMES]
    hdr, response = merge_images(images, TIMES)
    assert hdr.shape == (32, 48, 3) and hdr.dtype == torch.float32 and response.shape == (256, 3)
    unclipped = (images[0] < 255).all(axis=-1)  # below 255 in every channel of the shortest exposure
    assert unclipped.sum() == 32 * 48 - 36
    scale, rel = errors(hdr, e, unclipped)
    # The scale is fixed by the response's code 255 (= the camera's clip level, E t = 1): it matches
    # the truth's to a few percent (the curve's last codes are extrapolated), per channel.
    assert np.all(np.abs(scale - 1) < 0.04), scale
    # Over the unclipped pixels, after that per-channel factor: 0.5% on average, 1.5% at the 99th
    # percentile, 2.5% at worst (the pixels that just clip in one exposure, which OpenCV's merge still
    # weighs a little).
    assert rel.mean() < 0.01 and np.percentile(rel, 99) < 0.02 and rel.max() < 0.035, (rel.mean(), np.percentile(rel, 99), rel.max())
    # A broken merge would miss this: red and blue swapped (OpenCV keeps BGR) are 10% off.
    assert errors(hdr, e[..., ::-1], unclipped)[1].mean() > 0.05
    # Pixels clipped even at 1/8 s hold their lower bound, 1 / t_min.
    assert torch.equal(hdr[:6, :6], torch.full((6, 6, 3), 8.0))
    # The recovered curve is the camera's inverse response (up to the factor), away from the ends.
    codes = np.arange(16, 251)
    truth = np.interp(codes / 255, srgb(np.linspace(0, 1, 100001)), np.linspace(0, 1, 100001))
    curve = response.numpy()[codes] / scale
    assert np.abs(curve / truth[:, None] - 1).max() < 0.03


def test_synthetic_bracket_through_a_response_with_a_shoulder():
    e = radiance()
    images = [photograph(e, t, film) for t in TIMES]
    hdr, _ = merge_images(images, TIMES)
    scale, rel = errors(hdr, e, (images[0] < 255).all(axis=-1))
    assert np.all(np.abs(scale - 1) < 0.08), scale  # the shoulder spreads the top codes: a looser scale
    assert rel.mean() < 0.01 and np.percentile(rel, 99) < 0.02, (rel.mean(), np.percentile(rel, 99))


def test_exposure_times_in_the_wrong_order_are_an_error():
    """Exposure times in the wrong order give a decreasing curve: an error, not a wrong image."""
    images = [photograph(radiance(), t) for t in TIMES]
    with pytest.raises(ParameterError, match="does not increase"):
        merge_images(images, TIMES[::-1].copy())


def _rows(text):
    lines = text.splitlines()
    return lines[0], np.array([[float(v) for v in line.split(",")] for line in lines[1:]])


def test_response_csv_format(tmp_path):
    e = radiance(16, 24)
    _, response = merge_images([photograph(e, t) for t in TIMES], TIMES)
    write_response_csv(tmp_path / "curve.csv", response)
    header, rows = _rows((tmp_path / "curve.csv").read_text())
    assert header == CSV_HEADER == "value,red,green,blue"
    assert rows.shape == (256, 4)
    assert np.array_equal(rows[:, 0], np.arange(256) / 255)  # code / 255, exactly as printed
    assert np.all(np.diff(rows, axis=0) > 0)  # value and every channel strictly increasing
    assert np.array_equal(rows[-1], [1.0, 1.0, 1.0, 1.0]) and np.all(rows[0, 1:] > 0)
    np.testing.assert_allclose(rows[:, 1:], response.numpy(), rtol=1e-7)
    assert [p.name for p in tmp_path.iterdir()] == ["curve.csv"]


@pytest.mark.parametrize("bad", [np.ones((256, 3)), np.linspace(0.1, 1, 256)[:, None].repeat(3, 1) * 2, np.linspace(0.1, 1, 256)[:, None].repeat(2, 1),
                                 np.linspace(0.1, 1, 256)[::-1, None].repeat(3, 1)])
def test_response_csv_refuses_a_curve_out_of_format(tmp_path, bad):
    with pytest.raises(ParameterError, match="response"):
        write_response_csv(tmp_path / "curve.csv", bad)
    assert not any(tmp_path.iterdir())
    with pytest.raises(ParameterError):
        response_csv(torch.as_tensor(bad))


# --- the command ---------------------------------------------------------------------------------


def run(args, capsys):
    try:
        code = main(args)
    except SystemExit as e:  # argparse's usage errors
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def _bracket(tmp_path, suffix=".png", exif=False, size=(12, 18)):
    """A tiny bracket of three files; with ``exif``, JPEGs that carry their exposure times."""
    e = radiance(*size)
    tmp_path.mkdir(exist_ok=True)
    paths = []
    for t in TIMES[:3]:
        path = tmp_path / f"shot_{t:g}{suffix}"
        img = Image.fromarray(photograph(e, t))
        if exif:
            tags = Image.Exif()
            tags.get_ifd(ExifTags.IFD.Exif)[ExifTags.Base.ExposureTime] = IFDRational(*float(t).as_integer_ratio())
            img.save(path, exif=tags, quality=95)
        else:
            img.save(path)
        paths.append(str(path))
    return paths


def test_cli_end_to_end(tmp_path, capsys):
    paths = _bracket(tmp_path)
    out = tmp_path / "out" / "merged.exr"
    code, stdout, err = run(["hdr", "--out", str(out), *paths, "--exposures", "1/8,0.5,2"], capsys)
    assert code == 0, err
    assert "merged 3 images (18x12)" in stdout
    hdr, response = merge_bracket(paths, [1 / 8, 0.5, 2])
    assert torch.equal(read_image(out), hdr)
    header, rows = _rows((tmp_path / "out" / "merged.response.csv").read_text())
    assert header == CSV_HEADER and rows.shape == (256, 4)
    np.testing.assert_allclose(rows[:, 1:], response.numpy(), rtol=1e-7)
    with Image.open(tmp_path / "out" / "merged.response.png") as plot:
        assert plot.format == "PNG" and plot.width > 300
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["merged.exr", "merged.response.csv", "merged.response.png"]


def test_cli_reads_exif_exposure_times(tmp_path, capsys):
    paths = _bracket(tmp_path, ".jpg", exif=True)
    curve, plot = tmp_path / "c.csv", tmp_path / "p.png"
    code, _, err = run(["hdr", "--out", str(tmp_path / "m.exr"), *paths, "--curve", str(curve), "--plot", str(plot)], capsys)
    assert code == 0, err
    assert curve.exists() and plot.exists()
    hdr, _ = merge_bracket(paths, list(TIMES[:3]))  # the EXIF times are the ones the bracket was taken at
    assert torch.equal(read_image(tmp_path / "m.exr"), hdr)


def _corrupt(tmp_path, paths):
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    return [paths[0], str(bad)], "broken.png"


def _resized(tmp_path, paths):
    other = _bracket(tmp_path / "small", size=(8, 10))
    return [paths[0], other[1]], "10x8"


def _sixteen_bit(tmp_path, paths):
    deep = tmp_path / "deep.png"
    Image.fromarray(np.full((12, 18), 30000, np.uint16)).save(deep)
    return [paths[0], str(deep)], "deep.png: not an 8-bit image"


def _sixteen_bit_rgb(tmp_path, paths):
    """A 16-bit RGB PNG, which PIL opens as mode RGB (its codes cut to 8 bits) unless asked."""
    import cv2

    deep = tmp_path / "deep_rgb.png"
    cv2.imwrite(str(deep), np.full((12, 18, 3), 30000, np.uint16))
    return [paths[0], str(deep)], "deep_rgb.png: not an 8-bit image (16 bits per channel)"


BAD = {
    "missing file": (lambda tmp, p: ([p[0], str(tmp / "nope.png")], ["--exposures", "1,2"]), "nope.png: file not found"),
    "corrupt file": (lambda tmp, p: (_corrupt(tmp, p)[0], ["--exposures", "1,2"]), "broken.png: not a valid image"),
    "different sizes": (lambda tmp, p: (_resized(tmp, p)[0], ["--exposures", "1,2"]), "10x8"),
    "16-bit image": (lambda tmp, p: (_sixteen_bit(tmp, p)[0], ["--exposures", "1,2"]), "deep.png: not an 8-bit image"),
    "16-bit RGB image": (lambda tmp, p: (_sixteen_bit_rgb(tmp, p)[0], ["--exposures", "1,2"]), "deep_rgb.png: not an 8-bit image (16 bits per channel)"),
    "count mismatch": (lambda tmp, p: (p, ["--exposures", "1,2"]), "2 exposure times for 3 images"),
    "zero time": (lambda tmp, p: (p, ["--exposures", "1,0,2"]), "exposure time 0.0; expected a finite number > 0"),
    "negative time": (lambda tmp, p: (p, ["--exposures", "1,-2,4"]), "exposure time -2.0"),
    "infinite time": (lambda tmp, p: (p, ["--exposures", "1,inf,4"]), "exposure time inf"),
    "nan time": (lambda tmp, p: (p, ["--exposures", "1,2,nan"]), "exposure time nan"),
    "unparsable time": (lambda tmp, p: (p, ["--exposures", "1,1/0,4"]), "--exposures"),
    "equal times": (lambda tmp, p: (p, ["--exposures", "2,2,2"]), "at least two different times"),
    "one image": (lambda tmp, p: (p[:1], ["--exposures", "1"]), "at least 2 images, got 1"),
    "no exif": (lambda tmp, p: (p, []), "no EXIF exposure time"),
    "csv suffix": (lambda tmp, p: (p, ["--exposures", "1,2,4", "--curve", str(tmp / "out" / "c.txt")]), "c.txt: unknown suffix"),
    "exr suffix": (lambda tmp, p: (p, ["--exposures", "1,2,4", "--out", str(tmp / "out" / "m.png")]), "m.png: unknown suffix"),
    "samples": (lambda tmp, p: (p, ["--exposures", "1,2,4", "--samples", "0"]), "--samples"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_cli_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, case):
    make, expected = BAD[case]
    images, flags = make(tmp_path, _bracket(tmp_path))
    out = ["--out", str(tmp_path / "out" / "m.exr")]
    code, _, err = run(["hdr", *out, *images, *flags], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and err.startswith("invrender: error: "), err
    assert expected in err, err
    assert not (tmp_path / "out").exists()


def test_library_errors_name_the_file(tmp_path):
    paths = _bracket(tmp_path)
    with pytest.raises(ParameterError, match=r"shot_0\.125\.png: no EXIF exposure time"):
        merge_bracket(paths)
    with pytest.raises(ImageError, match="nope.png"):
        merge_bracket([paths[0], tmp_path / "nope.png"], [1, 2])
    with pytest.raises(ParameterError, match=r"shot_0\.5\.png: exposure time -1"):
        merge_bracket(paths, [1, -1, 2])
    with pytest.raises(ParameterError, match="smoothness"):
        merge_bracket(paths, [1, 2, 4], smoothness=0.0)


def test_grey_and_palette_images_are_8_bit(tmp_path):
    e = radiance(12, 18)
    paths = []
    for t in TIMES[:3]:
        buf = io.BytesIO()
        Image.fromarray(photograph(e, t)[..., 1]).save(buf, format="PNG")  # mode L
        (tmp_path / f"g{t:g}.png").write_bytes(buf.getvalue())
        paths.append(tmp_path / f"g{t:g}.png")
    hdr, response = merge_bracket(paths, list(TIMES[:3]))
    assert torch.equal(hdr[..., 0], hdr[..., 2]) and torch.equal(response[:, 0], response[:, 1])


def test_the_recovered_curve_is_a_response_fit_accepts(tmp_path):
    """The CSV ``invrender hdr`` writes is what ``response=`` reads: decoding each code gives the
    curve's value, and the recovered curve decodes an sRGB photograph within 3% of the sRGB
    response itself (after the per-channel scale)."""
    from invrender.io.response import response as make_response

    e = radiance()
    _, curve = merge_images([photograph(e, t) for t in TIMES], TIMES)
    path = tmp_path / "curve.csv"
    write_response_csv(path, curve)
    read = make_response(str(path))
    codes = torch.arange(256, dtype=torch.float64) / 255
    decoded = read.decode(codes[:, None].expand(256, 3).contiguous())
    torch.testing.assert_close(decoded.float(), curve / curve[-1], rtol=1e-6, atol=1e-7)
    truth = make_response("srgb").decode(codes[:, None].expand(256, 3).contiguous())
    mid = slice(16, 251)
    ratio = decoded[mid] / truth[mid]
    assert float((ratio / ratio.median(0).values - 1).abs().max()) < 0.03


def test_cli_refuses_a_16_bit_bracket_in_a_child_process(tmp_path):
    """As the docs say: a 16-bit PNG in a bracket is refused (not reduced to 8 bits), in one line
    naming the file, before anything is written."""
    from tests.conftest import refused

    images, expected = _sixteen_bit_rgb(tmp_path, _bracket(tmp_path))
    line = refused(tmp_path, "hdr", *images, "--exposures", "1,2", out="out/m.exr")
    assert expected in line and "(OpenCV's Debevec calibration and merge take 8-bit codes only)" in line
    assert not (tmp_path / "out").exists()
