"""Shared fixtures: small scenes, CPU only, fixed seeds."""

import pytest
import torch

import invrender as ir

torch.set_num_threads(1)  # pytest -n 2 runs two workers on the two cores


@pytest.fixture(scope="session")
def cbox32():
    return ir.load_scene("cornell_box", resolution=(32, 32))


def furnace(rho=0.5, eps=1.0, resolution=(16, 16)):
    return ir.load_scene("furnace", resolution=resolution, rho=rho, eps=eps)
