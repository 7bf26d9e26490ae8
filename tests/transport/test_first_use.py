"""The first use's compiles: announced on stderr once, only where a render shows progress; their
seconds counted so that ``invrender render`` leaves them out of its speed; and the test of Warp's
cache that decides whether a load compiles."""

import time

import pytest
import torch

import invrender as ir
from invrender import first_use


def test_a_compile_is_announced_once_and_only_where_progress_shows(capsys):
    what = "the test's kernels"
    with first_use.compiling(what, cached=False):  # no render showing progress: silent
        pass
    assert capsys.readouterr().err == ""
    before = first_use.seconds()
    with first_use.announcing(True):
        with first_use.compiling(what, cached=True):  # from the cache: silent
            time.sleep(0.02)
        assert capsys.readouterr().err == ""
        for _ in range(2):
            with first_use.compiling(what, cached=False):
                pass
    err = capsys.readouterr().err
    assert err.count("invrender: compiling the test's kernels (first use") == 1, err
    assert first_use.seconds() - before >= 0.02


@pytest.mark.warp
def test_the_bvh_kernels_are_in_warps_cache_once_loaded():
    """warp_bvh._cached reads Warp's cache layout (a folder per module identifier, block size 1 on
    the CPU): after a load it must say cached, or a first use would never be told apart."""
    from invrender.backends import warp_bvh

    cpu = torch.device("cpu")
    warp_bvh.load(cpu)
    assert warp_bvh._cached(warp_bvh.wp.device_from_torch(cpu))


def test_render_cli_leaves_compiling_out_of_its_speed(tmp_path, monkeypatch, capsys):
    """The summary's seconds are the render's less the first use's: a 3 s 'compile' is reported
    apart, not in the M paths/s."""
    from invrender.cli import main

    real = ir.render

    def render_after_a_compile(*args, **kwargs):
        with first_use.compiling("nothing", cached=True):
            time.sleep(3.0)
        return real(*args, **kwargs)

    monkeypatch.setattr(ir, "render", render_after_a_compile)
    code = main(["render", "cornell_box", "--resolution", "4x4", "--spp", "1", "--out", str(tmp_path / "a.exr")])
    err = capsys.readouterr().err
    assert code == 0, err
    line = next(x for x in err.splitlines() if "M paths/s" in x)
    seconds = float(line.split(" spp, ")[1].split(" s ")[0])
    assert seconds < 2.5 and "+ 3.0 s compiling kernels on first use" in line, line
