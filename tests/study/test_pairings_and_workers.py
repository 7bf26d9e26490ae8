"""The control-variate pairing (dl/dI at a recursive control variate built along a short chain of
steps) and trials drawn on several workers."""

import os

import pytest
import torch

import invrender as ir
from invrender.study import parse_config, setup
from invrender.study.loss_gradients import LOSS_GRADIENTS, Objective
from invrender.study.trials import gradient_sample, pixel_contributions

PARAMS = ["red.reflectance", "light.emission"]


@pytest.fixture(scope="module")
def cbox6():
    return ir.load_scene("cornell_box", resolution=(6, 6))


def _objective(scene, at=0.5, loss="relative_l2"):
    work = scene.with_params(detach=True)
    setup.move_to(work, PARAMS, at)
    for n in PARAMS:
        work.params[n].requires_grad_(True)
    target = ir.render(scene, spp=64, seed=777, progress=False)
    return Objective(work, target, loss)


def test_control_variate_pixel_contributions_add_up_to_its_gradient(cbox6):
    """The chain is a pure function of the trial's seed: the per-pixel map (which builds its own
    chain) and the gradient see the same dl/dI."""
    objective = _objective(cbox6)
    config = parse_config("path/replay/control_variate/cv_steps=3/cv_step=0.05")
    g, cpu, wall = gradient_sample(objective, PARAMS, config, 2, 4)
    assert cpu > 0 and wall > 0 and bool(g.abs().sum() > 0)
    for k, name in enumerate(PARAMS):
        c = pixel_contributions(objective, name, config, 2, 4)
        assert torch.allclose(c.sum((0, 1)), g[3 * k : 3 * k + 3], rtol=1e-4, atol=1e-10), name


def test_control_variate_chain_steps_toward_the_point(cbox6):
    """cv_steps renders of the chain's points before the last; the last one is at the point."""
    objective = _objective(cbox6)
    config = parse_config("path/replay/control_variate/cv_steps=4/cv_step=0.1")
    pairing = LOSS_GRADIENTS["control_variate"]()
    cv = pairing.prepare(objective, config, 2, 0)
    eps = objective.scene.params["light.emission"].detach()
    assert torch.allclose(cv.values["light.emission"], eps * torch.exp(torch.tensor(-0.1)), rtol=1e-5)  # one step (log units) before
    pairing.adjoint(objective, config, 2, 0, None, cv)
    assert torch.allclose(cv.values["light.emission"], eps)


def test_control_variate_lowers_the_variance_near_the_target(cbox6):
    """At the target's values (dl/dI all noise) a chain that stays at the point (cv_step 0)
    averages its renders: the gradient's variance falls well below the decorrelated one's."""
    study = ir.gradient_study(
        cbox6, PARAMS, ["path/replay/decorrelated", "path/replay/control_variate/cv_steps=6/cv_step=0"], spp=[2], trials=16, at=1.0,
        target_spp=64, reference_spp=0, pixel_maps=False, progress=False,
    )  # fmt: skip
    plain = study.summary("path/replay/decorrelated", 2, "parameter").moments.variance
    cv = study.summary("path/replay/control_variate/cv_step=0/cv_steps=6", 2, "parameter").moments.variance
    assert bool((plain > 2 * cv).all()), (plain, cv)


def test_workers_trace_on_one_core_each(cbox6):
    """A worker sees one core (the driver and Embree then trace in its thread, so its CPU time is
    the gradient's whole cost) and torch runs single-threaded in it."""
    from invrender.study.gradients import _Workers
    from invrender.core.driver import cpu_workers

    objective = _objective(cbox6)
    threads, cores = torch.get_num_threads(), os.sched_getaffinity(0)

    class Bar:
        def update(self, n):
            pass

    with _Workers(objective, PARAMS, 2) as pool:
        seen = pool.map(lambda own, t: (cpu_workers(torch.device("cpu")), torch.get_num_threads(), own), 4, Bar())
    assert {s[:2] for s in seen} == {(1, 1)}
    assert len({id(s[2].scene.params["light.emission"]) for s in seen}) <= 2  # leaves of their own per worker
    assert (torch.get_num_threads(), os.sched_getaffinity(0)) == (threads, cores)  # the caller's settings untouched


def test_samples_do_not_depend_on_the_workers(cbox6):
    kwargs = {"spp": [1, 2], "trials": 5, "target_spp": 32, "reference_spp": 4, "reference_repeats": 2, "pixel_spp": 1, "progress": False}
    configs = ["path/autodiff/correlated", "path/replay/control_variate/cv_steps=2"]
    one = ir.gradient_study(cbox6, PARAMS, configs, workers=1, **kwargs)
    two = ir.gradient_study(cbox6, PARAMS, configs, workers=3, **kwargs)
    for a, b in zip(one.runs, two.runs):
        assert torch.allclose(a.samples, b.samples, rtol=1e-5, atol=1e-10), a.config.label
    for a, b in zip(one.pixel_maps, two.pixel_maps):
        assert torch.allclose(a.variance, b.variance, rtol=1e-5, atol=1e-12)
    assert torch.allclose(one.references["path/autodiff/correlated"].samples, two.references["path/autodiff/correlated"].samples, rtol=1e-5, atol=1e-10)
