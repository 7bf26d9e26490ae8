"""Independent estimators and set-ups agree: path vs random walk, terms vs full image,
Embree vs torch intersection, any chunk size."""

import math

import pytest
import torch

import invrender as ir


def block_means(img, block=8):
    """(H, W, 3) -> (H/block, W/block, 3) block averages."""
    h, w, _ = img.shape
    return img.reshape(h // block, block, w // block, block, 3).mean(dim=(1, 3))


def test_path_and_random_walk_agree_on_cornell_box(cbox32):
    """Four independent seeds per integrator give each estimate's standard error; the difference of
    the two means must lie within 5 standard errors (channel means and 8x8-pixel blocks).
    The light is small, so the random walk is the noisier one; both are unbiased."""
    seeds = range(4)
    runs = {
        name: torch.stack([block_means(ir.render(cbox32, integrator=name, spp=128, max_depth=5, seed=s, progress=False)) for s in seeds])
        for name in ("path", "random_walk")
    }
    means = {k: v.mean(0) for k, v in runs.items()}
    stderr = {k: v.std(0) / math.sqrt(len(seeds)) for k, v in runs.items()}
    sigma = (stderr["path"] ** 2 + stderr["random_walk"] ** 2).sqrt()
    diff = (means["path"] - means["random_walk"]).abs()
    assert (diff <= 5 * sigma + 1e-4).all(), (diff / sigma).max()
    channel = {k: v.mean(dim=(1, 2)) for k, v in runs.items()}  # (seeds, 3)
    sigma_c = ((channel["path"].var(0) + channel["random_walk"].var(0)) / len(seeds)).sqrt()
    assert ((channel["path"].mean(0) - channel["random_walk"].mean(0)).abs() <= 5 * sigma_c).all()
    rel = ((channel["path"].mean(0) - channel["random_walk"].mean(0)).abs() / channel["path"].mean(0)).max()
    assert rel < 0.03


@pytest.mark.parametrize("integrator", ["path", "random_walk"])
def test_terms_sum_to_full_image(cbox32, integrator):
    full = ir.render(cbox32, integrator=integrator, spp=8, max_depth=6, seed=1, progress=False)
    terms = ir.render(cbox32, integrator=integrator, spp=8, max_depth=6, seed=1, terms=True, progress=False)
    assert terms.shape == (6, 32, 32, 3)
    assert torch.allclose(terms.sum(0), full, rtol=1e-5, atol=1e-6)
    # term 0 is the light seen directly: only the pixels that see the light are non-zero
    lit = terms[0].sum(-1) > 0
    assert 0 < lit.sum() < 0.05 * lit.numel()
    light = torch.tensor([18.387, 13.9873, 6.75357])
    inside = terms[0].reshape(-1, 3)[lit.reshape(-1)]
    assert (inside <= light * (1 + 1e-6)).all()  # edge pixels see the light partly
    assert torch.allclose(inside.amax(0), light, rtol=1e-6)  # interior pixels see exactly eps


def test_max_depth_counts_as_mitsuba(cbox32):
    """max_depth D keeps exactly terms 0 .. D-1."""
    terms = ir.render(cbox32, spp=4, max_depth=8, seed=0, terms=True, progress=False)
    for depth in (1, 2, 3):
        img = ir.render(cbox32, spp=4, max_depth=depth, seed=0, progress=False)
        assert torch.allclose(img, terms[:depth].sum(0), rtol=1e-5, atol=1e-6)


def test_identical_across_chunk_sizes(cbox32):
    a = ir.render(cbox32, spp=8, seed=5, progress=False)
    b = ir.render(cbox32, spp=8, seed=5, chunk_paths=997, progress=False)
    assert torch.equal(a, b)


def test_embree_and_torch_backends_agree(cbox32):
    """Same random numbers, different intersection arithmetic: rays grazing an edge may pick
    different triangles, so a handful of paths can diverge; everything else matches to rounding."""
    a = ir.render(cbox32, spp=8, seed=2, backend="embree", progress=False)
    b = ir.render(cbox32, spp=8, seed=2, backend="torch", progress=False)
    close = torch.isclose(a, b, rtol=1e-4, atol=1e-5).all(-1)
    assert close.float().mean() > 0.99
    assert (a.mean() - b.mean()).abs() / a.mean() < 1e-3


def test_different_seeds_differ(cbox32):
    a = ir.render(cbox32, spp=4, seed=0, progress=False)
    b = ir.render(cbox32, spp=4, seed=1, progress=False)
    assert not torch.equal(a, b)


def point_lit_box():
    """The Cornell box's walls lit by a point light instead of its area light (no emission is ever
    hit: the compiled bounce's emitted light is zero on every lane)."""
    from invrender.scene.emitters import Emitter
    from invrender.scene.scene import build_scene
    from invrender.scene.shapes import Mesh

    box = ir.load_scene("cornell_box", resolution=(32, 32))
    t = box.triangles
    corners = t.corners().numpy()
    walls = [Mesh(corners[i], [[0, 1, 2]], None, box.materials[int(t.material[i])], None) for i in range(t.count)]
    reflectance = {m: box.params[f"{m}.reflectance"] for m in box.materials}
    return build_scene(walls, reflectance, {"lamp": Emitter.of("point", emission=(1.0, 1.0, 1.0), position=(0.0, 0.5, 0.0))}, box.camera, (32, 32), name="point_box")


@pytest.mark.parametrize("lit", ["area", "point"])
def test_two_workers_give_the_same_image(cbox32, lit):
    """On the CPU one worker thread per core traces chunks into its own film: the image is the
    same as with one worker (the test session runs single-threaded, so force two here). With the
    point light, two workers' chunks replayed a frozen kernel with lane counts whose zero
    emission came back at another call's length."""
    scene = cbox32 if lit == "area" else point_lit_box()
    one = ir.render(scene, spp=32, seed=4, progress=False)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        from invrender.core.driver import cpu_workers

        assert cpu_workers(torch.device("cpu")) == 2
        two = ir.render(scene, spp=32, seed=4, progress=False)
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(one, two)
