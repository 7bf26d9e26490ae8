"""The C heap settings of the chunked renderer (docs/scale.md#where-a-renders-time-goes).

What the thresholds buy is measured, not asserted: a warm 128x128 render faulted in 70-1,200 pages
with them against 650-10,700 with glibc's defaults (seven pairs of runs; the counts vary from run
to run with the heap's layout, so a test of them would be flaky). Here: they are set where glibc
is, once, and the opt-out leaves the allocator alone."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SNIPPET = "from invrender.core import memory; print(memory.keep_freed_blocks(), memory.keep_freed_blocks())"


def run(env_value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "INVRENDER_MALLOC"}
    if env_value is not None:
        env["INVRENDER_MALLOC"] = env_value
    return subprocess.run([sys.executable, "-c", SNIPPET], env=env, capture_output=True, text=True, check=True).stdout.strip()


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_heap_thresholds_are_set_once_and_can_be_left_alone():
    assert run(None) == "True True"  # set (mallopt accepted both), then already set
    assert run("default") == "False False"


def test_a_render_sets_them():
    import invrender as ir
    from invrender.core import memory

    ir.render(ir.load_scene("cornell_box", resolution=(4, 4)), spp=1, progress=False)
    assert memory._done == (sys.platform.startswith("linux") and os.environ.get("INVRENDER_MALLOC", "") != "default")
