"""Shared fixtures: small scenes, CPU only, fixed seeds."""

import pytest
import torch

import invrender as ir

torch.set_num_threads(1)  # pytest -n 2 runs two workers on the two cores


def pytest_collection_modifyitems(config, items):
    """Tests marked ``cuda`` are skipped where torch sees no CUDA device."""
    if not torch.cuda.is_available():
        skip = pytest.mark.skip(reason="needs a CUDA device")
        for item in items:
            if item.get_closest_marker("cuda") is not None:
                item.add_marker(skip)


@pytest.fixture(scope="session")
def cbox32():
    return ir.load_scene("cornell_box", resolution=(32, 32))


def furnace(rho=0.5, eps=1.0, resolution=(16, 16)):
    return ir.load_scene("furnace", resolution=resolution, rho=rho, eps=eps)
