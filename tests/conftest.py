"""Shared fixtures: small scenes, CPU only, fixed seeds."""

import pytest
import torch

import invrender as ir

torch.set_num_threads(1)  # pytest -n 2 runs two workers on the two cores


def pytest_collection_modifyitems(config, items):
    """Tests marked ``cuda`` are skipped where torch sees no CUDA device, those marked ``warp``
    where warp-lang cannot be imported (a GPU machine without Warp)."""
    from invrender.transport import packages

    missing = {"cuda": None if torch.cuda.is_available() else "needs a CUDA device",
               "warp": None if packages.find("warp") else "needs warp-lang (pip install warp-lang)"}  # fmt: skip
    for item in items:
        for mark, reason in missing.items():
            if reason and item.get_closest_marker(mark) is not None:
                item.add_marker(pytest.mark.skip(reason=reason))


@pytest.fixture(scope="session")
def cbox32():
    return ir.load_scene("cornell_box", resolution=(32, 32))


def furnace(rho=0.5, eps=1.0, resolution=(16, 16)):
    return ir.load_scene("furnace", resolution=resolution, rho=rho, eps=eps)
