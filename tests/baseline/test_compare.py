"""invrender compare: pyrender, utah, path at max_depth 2 and the full path side by side."""

import pytest
import torch

import invrender as ir
from invrender.baseline.compare import compare, fit_ambient, format_table
from invrender.cli import main


@pytest.mark.slow
def test_fit_ambient_recovers_the_eps0_of_a_utah_image(cbox32):
    """utah is affine in eps0, so the least-squares eps0 of a utah image (same seed) is its own."""
    eps0 = torch.tensor([0.12, 0.05, 0.3])
    reference = ir.render(cbox32.with_ambient(eps0), "utah", spp=4, seed=9, progress=False)
    assert torch.allclose(fit_ambient(cbox32, reference, spp=4, seed=9), eps0, rtol=1e-4)


def test_comparison_on_the_cornell_box(cbox32):
    c = compare(cbox32, spp=16, seed=0, progress=False)
    assert list(c.images) == ["pyrender", "utah", "path, max_depth 2", "utah, eps0 fitted", "path"]
    assert c.pyrender_error is None
    rel = c.relative_differences()
    torch.testing.assert_close(c.images["utah"], c.images["path, max_depth 2"], rtol=1e-5, atol=1e-7)  # no ambient: the same estimate (path compiled)
    # the Utah approximation drops the interreflected light: about a third of red, an eighth of blue
    assert (rel["utah"] < -0.08).all() and (rel["utah"] > -0.5).all()
    assert (rel["utah, eps0 fitted"].abs() < 0.02).all()  # a constant ambient recovers the mean
    # pyrender: the same model; away from the light's own pixels and their neighbours (whose edge
    # coverage a 4x4 grid of sub-pixels estimates coarsely, and one bright edge pixel sways a mean)
    # it is 7-9% darker, mostly its diffuse factor 0.96 (1 - F) ~ 0.92
    light = ir.render(cbox32, "path", max_depth=1, spp=4, progress=False).sum(-1) > 0
    off_light = torch.nn.functional.max_pool2d(light[None, None].float(), 3, stride=1, padding=1)[0, 0] == 0
    ratio = c.images["pyrender"][off_light].mean(0) / c.images["utah"][off_light].mean(0)
    assert ((ratio > 0.85) & (ratio < 0.97)).all(), ratio
    assert (c.eps0_fit > 0).all() and (c.eps0 == 0).all()
    assert "eps0 fitted" in format_table(c)


def test_compare_command_writes_the_figure(tmp_path, capsys):
    out = tmp_path / "c.png"
    assert main(["compare", "cornell_box", "--resolution", "24x24", "--spp", "8", "--ambient", "0.02", "--out", str(out), "--quiet"]) == 0
    assert out.stat().st_size > 10_000
    table = capsys.readouterr().out
    assert "pyrender" in table and "utah, eps0 fitted" in table and "drops" in table


@pytest.mark.parametrize(
    "argv, message",
    [
        (["compare", "--out", "x.exr"], "is a .png"),
        (["compare", "--spp", "0", "--out", "x.png"], "spp must be positive"),
        (["compare", "nowhere.toml", "--out", "x.png"], "not found"),
        (["compare", "--ambient", "-1", "--out", "x.png"], "R,G,B"),
    ],
)
def test_compare_bad_input(argv, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's usage errors
        code = e.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_baseline_command_writes_the_rasterized_image(tmp_path, capsys):
    out = tmp_path / "b.exr"
    assert main(["baseline", "cornell_box", "--resolution", "20x16", "--out", str(out), str(tmp_path / "b.png"), "--quiet"]) == 0
    image = ir.read_image(out)
    assert image.shape == (16, 20, 3) and (tmp_path / "b.png").is_file()
    assert image[..., 0].mean() > image[..., 2].mean() > 0  # the Cornell box's warm light
    assert main(["baseline", "cornell_box", "--out", str(tmp_path / "b.tif")]) == 2
    assert "unknown image suffix" in capsys.readouterr().err
