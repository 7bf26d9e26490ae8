"""Camera responses: round trips, tabulated curves and their checks."""

from __future__ import annotations

import pytest
import torch

from invrender.errors import ImageError
from invrender.io.response import read_response_csv, response, write_response_csv


@pytest.mark.parametrize("name", ["srgb", "gamma:2.2", "gamma:1.8", "linear"])
def test_responses_round_trip(name):
    x = torch.rand(4096, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    x[:4] = torch.tensor([0.0, 1e-9, 1e-6, 1.0], dtype=torch.float64)[:, None]  # the ends
    r = response(name)
    assert float((r.decode(r.encode(x)) - x).abs().max()) < 1e-6
    assert float((r.encode(r.decode(x)) - x).abs().max()) < 1e-6
    y = torch.rand(64, 3)  # float32 too
    assert float((r.decode(r.encode(y)) - y).abs().max()) < 1e-6


def test_srgb_is_the_standard_curve():
    r = response("srgb")
    x = torch.tensor([[0.0, 0.002, 0.0031308], [0.18, 0.5, 1.0]], dtype=torch.float64)
    expected = torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    torch.testing.assert_close(r.encode(x), expected)
    assert abs(float(r.encode(torch.tensor(0.18, dtype=torch.float64).expand(3))[0]) - 0.46135612950044) < 1e-9


def test_responses_are_differentiable():
    x = torch.full((2, 3), 0.25, dtype=torch.float64, requires_grad=True)
    response("gamma:2").encode(x).sum().backward()
    torch.testing.assert_close(x.grad, torch.full((2, 3), 0.5 * 0.25**-0.5, dtype=torch.float64))


def test_a_tabulated_response_reproduces_a_known_curve(tmp_path):
    """A 256-code table of per-channel gamma curves: exact at the codes, within the linear
    interpolation's error between them, and inverted by encode."""
    codes = torch.linspace(0, 1, 256, dtype=torch.float64)
    gammas = torch.tensor([2.0, 2.2, 2.4], dtype=torch.float64)
    path = tmp_path / "response.csv"
    write_response_csv(path, codes, codes[:, None] ** gammas)
    assert path.read_text().splitlines()[0] == "value,red,green,blue"
    r = response(str(path))
    assert r.name == str(path)
    torch.testing.assert_close(r.decode(codes[:, None].expand(256, 3)), codes[:, None] ** gammas)
    y = torch.rand(1000, 3, dtype=torch.float64)
    assert float((r.decode(y) - y**gammas).abs().max()) < 2e-5  # h^2 / 8 * max |f''| at h = 1/255
    assert float((r.encode(r.decode(y)) - y).abs().max()) < 1e-9
    assert response(path).table is not None  # a Path object works too


@pytest.mark.parametrize(
    "spec, message",
    [("sepia", "unknown response 'sepia'"), ("srbg", r"unknown response 'srbg' \(did you mean 'srgb'\?\)"), ("gamma:-1", "positive number"), ("gamma:x", "positive number")],
)
def test_bad_response_names(spec, message):
    with pytest.raises(ImageError, match=message):
        response(spec)


def test_bad_response_curves_name_the_file(tmp_path):
    bad = tmp_path / "bent.csv"
    bad.write_text("value,red,green,blue\n0,0,0,0\n0.5,0.3,0.6,0.2\n0.7,0.9,0.5,0.6\n1,1,1,1\n")
    with pytest.raises(ImageError, match=r"bent\.csv: not monotonic: the green column"):
        read_response_csv(bad)
    header = tmp_path / "header.csv"
    header.write_text("code,r,g,b\n0,0,0,0\n1,1,1,1\n")
    with pytest.raises(ImageError, match=r"header\.csv: the header must be value,red,green,blue"):
        response(str(header))
    top = tmp_path / "top.csv"
    top.write_text("value,red,green,blue\n0,0,0,0\n1,0.9,1,1\n")
    with pytest.raises(ImageError, match=r"top\.csv: .*1\.0 at the largest code"):
        response(str(top))
    with pytest.raises(ImageError, match=r"missing\.csv"):
        response(str(tmp_path / "missing.csv"))
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\xff\xfe\x00 not text")
    with pytest.raises(ImageError, match=r"^response curve .*binary\.csv: not a CSV text file \(UnicodeDecodeError: "):
        response(str(binary))
