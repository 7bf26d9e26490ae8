"""``invrender variance``: a small study writes its tables and figures; bad input is one line,
exit status 2, no traceback and nothing written."""

import json

import pytest

from invrender.cli import main


def run(args, capsys):
    code = main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_small_study_writes_tables_and_figures(tmp_path, capsys):
    out = tmp_path / "study"
    args = ["variance", "cornell_box", "--params", "red.reflectance", "--out", str(out), "--resolution", "6x6", "--spp", "1,2",
            "--trials", "3", "--configs", "path/replay/correlated,path/autodiff/decorrelated", "--target-spp", "16",
            "--reference-spp", "8", "--reference-repeats", "2", "--loss", "relative_l2", "--quiet"]  # fmt: skip
    code, _, err = run(args, capsys)
    assert code == 0, err
    names = {p.name for p in out.iterdir()}
    assert names == {"results.csv", "results.json", "samples.pt", "variance.png", "bias.png", "pixel_variance.png"}
    data = json.loads((out / "results.json").read_text())
    assert data["loss"] == "relative_l2" and data["spp"] == [1, 2] and data["trials"] == 3
    assert data["at"]["red.reflectance"] == pytest.approx([0.285034, 0.021507, 0.022185], rel=1e-4)  # half the red wall's rho


def test_furnace_check_writes_its_table(tmp_path, capsys):
    out = tmp_path / "furnace"
    args = ["variance", "furnace", "--out", str(out), "--resolution", "4x4", "--spp", "1", "--trials", "4",
            "--configs", "random_walk/autodiff/correlated/max_depth=-1/rr_depth=1", "--params", "glow.emission"]  # fmt: skip
    code, stdout, err = run(args, capsys)
    assert code == 0, err
    assert "Furnace check" in stdout and "random_walk/autodiff/correlated/max_depth=-1/rr_depth=1" in stdout
    assert {"check.md", "check.json", "results.csv", "variance.png", "bias.png"} <= {p.name for p in out.iterdir()}


def test_out_defaults_to_runs_variance_scene(tmp_path, capsys, monkeypatch):
    """``invrender variance furnace`` as the README writes it, without --out: into runs/variance/furnace."""
    monkeypatch.chdir(tmp_path)
    args = ["variance", "furnace", "--resolution", "4x4", "--spp", "1", "--trials", "3", "--configs", "path/replay/correlated", "--params", "glow.emission", "--quiet"]
    code, _, err = run(args, capsys)
    assert code == 0, err
    assert {"check.md", "results.csv"} <= {p.name for p in (tmp_path / "runs" / "variance" / "furnace").iterdir()}


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--spp", ""], "spp list is empty"),
        (["--spp", "4,x"], "comma-separated integers"),
        (["--trials", "1"], "trials must be >= 2"),
        (["--configs", "path/replay/wobbly"], "unknown part 'wobbly'"),
        (["--configs", ""], "no configurations"),
        (["--params", "red.reflectance,purple.reflectance"], "unknown parameter 'purple.reflectance'"),
        (["--params", ""], "needs --params"),
        (["--loss", "ssim"], "unknown loss"),
        (["--at", "0.5", "--init", "reflectance=0.4"], "--at or --init"),
    ],
)
def test_bad_input_is_one_line_exit_2(extra, words, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = ["variance", "cornell_box", "--params", "red.reflectance", "--out", "out", "--resolution", "4x4", *extra]
    code, _, err = run(args, capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("invrender: error:") and words in lines[0], err
    assert not any(tmp_path.iterdir())


def test_furnace_check_refuses_what_does_not_apply(tmp_path, capsys):
    code, _, err = run(["variance", "furnace", "--out", str(tmp_path / "f"), "--target", "t.exr"], capsys)
    assert code == 2 and "--target does not apply" in err and len(err.strip().splitlines()) == 1
