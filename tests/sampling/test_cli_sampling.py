"""The command line's sampling options: render's strategy flags and --adaptive, and `ablation`."""

from __future__ import annotations

import csv

import pytest

import invrender as ir
from invrender.cli import main


def test_render_adaptive_writes_the_sample_counts(tmp_path, capsys):
    out = tmp_path / "far.exr"
    assert main(["render", "forward/cornell_far.toml", "--resolution", "16x16", "--spp", "12", "--adaptive", "--rounds", "1", "--out", str(out), str(tmp_path / "far.png"), "--quiet"]) == 0
    assert (tmp_path / "far.spp.png").is_file()
    counts = ir.read_image(tmp_path / "far.spp.exr")
    assert int(counts[..., 0].sum()) == 12 * 16 * 16
    assert ir.read_image(tmp_path / "far.spp.png").shape == (16, 16, 3)


def test_render_with_every_strategy_flag(tmp_path):
    out = tmp_path / "x.png"
    args = ["render", "cornell_box", "--resolution", "8x8", "--spp", "4", "--strategy", "emitter", "--hemisphere", "uniform", "--rr-depth", "-1", "--out", str(out), "--quiet"]
    assert main(args) == 0 and out.is_file()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--rounds", "3"], "--rounds needs --adaptive"),
        (["--adaptive", "--target-error", "0"], "adaptive target_error must be a number > 0"),
        (["--strategy", "light"], "unknown strategy 'light'"),
        (["--integrator", "whitted", "--hemisphere", "uniform"], "integrator 'whitted' has no setting 'hemisphere'"),
    ],
)
def test_render_bad_sampling_flags_are_one_line_errors(tmp_path, capsys, args, message):
    out = tmp_path / "x.png"
    assert main(["render", "cornell_box", "--resolution", "4x4", "--spp", "8", "--out", str(out), "--quiet", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("invrender: error: ") and message in err and "\n" not in err
    assert not out.exists()


def test_ablation_writes_table_csv_and_figure(tmp_path, capsys):
    out = tmp_path / "abl"
    args = ["ablation", "cornell_box", "--resolution", "8x8", "--spp", "6,12", "--trials", "1", "--reference-spp", "96", "--strategies", "independent,adaptive", "--out", str(out), "--quiet"]
    assert main(args) == 0
    table = capsys.readouterr().out
    assert "| default |" in table and "| adaptive |" in table and "RMSE at" in table
    with open(out / "ablation.csv") as f:
        rows = list(csv.DictReader(f))
    assert {(r["variant"], r["spp"]) for r in rows} == {(v, s) for v in ("default", "independent", "adaptive") for s in ("6", "12")}
    assert all(float(r["rmse"]) > 0 and float(r["seconds"]) > 0 and float(r["cpu_seconds"]) > 0 for r in rows)
    assert (out / "ablation.png").stat().st_size > 10_000 and (out / "ablation.md").is_file()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--strategies", "sobol"], "unknown strategy 'sobol'"),
        (["--spp", "16,8"], "spp must be ascending positive integers"),
        (["--reference-spp", "16"], "reference_spp must be an integer >= 4 x the largest spp"),
    ],
)
def test_ablation_bad_input_is_a_one_line_error(tmp_path, capsys, args, message):
    assert main(["ablation", "cornell_box", "--resolution", "4x4", "--spp", "8", "--out", str(tmp_path / "a"), "--quiet", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
    assert not (tmp_path / "a").exists()
