"""The command line: renders, --help, and one-line errors with exit status 2 on bad input."""

import subprocess
import sys

import pytest
import torch

import invrender as ir
from invrender.cli import main


def run(args, capsys):
    try:
        code = main(args)
    except SystemExit as e:  # argparse's own refusals (an argument's type)
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def test_render_writes_exr_and_png(tmp_path, capsys):
    exr, png = tmp_path / "a.exr", tmp_path / "sub" / "a.png"
    code, _, err = run(["render", "cornell_box", "--spp", "4", "--resolution", "16x12", "--out", str(exr), str(png), "--quiet"], capsys)
    assert code == 0, err
    img = ir.read_image(exr)
    assert img.shape == (12, 16, 3)
    assert png.exists()
    expected = ir.render(ir.load_scene("cornell_box", resolution=(16, 12)), spp=4, seed=0, progress=False)
    assert torch.equal(img, expected)


def test_render_terms(tmp_path, capsys):
    out = tmp_path / "f.exr"
    code, _, err = run(["render", "furnace", "--integrator", "random_walk", "--max-depth", "3", "--spp", "1", "--resolution", "4x4", "--terms", "--out", str(out), "--quiet"], capsys)
    assert code == 0, err
    terms = [ir.read_image(tmp_path / f"f.term{k}.exr") for k in range(3)]
    assert torch.allclose(terms[0] + terms[1] + terms[2], ir.read_image(out))
    assert torch.allclose(terms[2], torch.full_like(terms[2], 0.25))


@pytest.mark.parametrize(
    "args, words",
    [
        (["render", "no_such_scene"], "unknown scene"),
        (["render", "missing.toml"], "not found"),
        (["render", "--integrator", "bogus"], "unknown integrator"),
        (["render", "--spp", "0"], "spp must be positive"),
        (["render", "--max-depth", "0"], "max_depth"),
        (["render", "--out", "x.jpg2"], "suffix"),
        (["render", "--backend", "optix"], "unknown intersection backend"),
        (["render", "--device", "tpu"], "unknown device 'tpu' (did you mean 'cpu'?)"),
    ],
)
def test_bad_input_is_one_line_exit_2(args, words, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(args + ["--resolution", "4x4", "--spp", "1"] if "--spp" not in args else args + ["--resolution", "4x4"], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("invrender: error:") and words in lines[0], err
    assert not any(tmp_path.iterdir())  # nothing written


def test_unwritable_output_fails_before_rendering(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = run(["render", "--resolution", "4x4", "--spp", "1", "--out", str(blocker / "img.exr")], capsys)
    assert code == 2 and "cannot write" in err and len(err.strip().splitlines()) == 1


def test_corrupt_scene_file(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("resolution = [16, \n")
    code, _, err = run(["render", str(bad), "--out", str(tmp_path / "o.exr")], capsys)
    assert code == 2 and "bad.toml" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o.exr").exists()


def test_console_script_help_and_bad_resolution():
    """Through a real process: --help explains the commands; argparse errors exit 2."""
    help_text = subprocess.run([sys.executable, "-m", "invrender.cli", "--help"], capture_output=True, text=True)
    assert help_text.returncode == 0 and "render" in help_text.stdout
    sub = subprocess.run([sys.executable, "-m", "invrender.cli", "render", "--help"], capture_output=True, text=True)
    assert "--max-depth" in sub.stdout and "Neumann" in sub.stdout
    for args in (["render", "--resolution", "64by64"], ["render", "--resolution", "0x4"], ["render", "--spp", "many"], ["paint"]):
        bad = subprocess.run([sys.executable, "-m", "invrender.cli", *args], capture_output=True, text=True)
        assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and bad.stderr.startswith("invrender"), bad.stderr


def test_an_unexpected_exception_is_one_line_exit_1(capsys, monkeypatch):
    """A bug (an exception that is not an InvRenderError) still ends in one line, exit 1, naming
    its type; INVRENDER_TRACEBACK=1 lets it through for a developer."""
    import invrender.cli.render as render_cmd

    def broken(args):
        raise ValueError("could not convert string to float: 'abc'\nsecond line")

    monkeypatch.setattr(render_cmd, "run", broken)
    assert main(["render", "cornell_box", "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("invrender: internal error: ValueError: could not convert string to float: 'abc' (a bug")
    monkeypatch.setenv("INVRENDER_TRACEBACK", "1")
    with pytest.raises(ValueError):
        main(["render", "cornell_box", "--quiet"])


def test_old_mitsuba_texture_offsets_that_are_not_numbers(tmp_path, capsys):
    """A Mitsuba 0.x file's uscale/uoffset (upgraded to a to_uv transform) that is not a number."""
    xml = tmp_path / "old.xml"
    xml.write_text(
        '<scene version="0.5.0"><bsdf type="diffuse" id="m"><texture type="bitmap" name="reflectance">'
        '<string name="filename" value="x.png"/><float name="uscale" value="abc"/></texture></bsdf>'
        '<shape type="sphere"><ref id="m"/></shape><emitter type="constant"/></scene>'
    )
    assert main(["render", str(xml), "--resolution", "8x8", "--out", str(tmp_path / "o.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"invrender: error: {xml}:1: <float name=\"uscale\">: could not parse a number from 'abc'"]
    assert not (tmp_path / "o.png").exists()
