"""Inverse lighting by the transport matrix (``ir.lighting.transport_matrix``, ``fit_map``).

Every image is exactly linear in an envmap's texels: the matrix rendered into a TexelFilm must
give the render of the same seed back to float rounding; its halves' ``sym(A1^T A2)`` must be an
unbiased estimate of ``A^T A`` where the halves' mean's Gram is not; the regularized non-negative
solve with the discrepancy principle's weight must recover a map that relights a held-out view, at
a weight whose held-out error is within 1.5x of the best of a sweep; bad inputs are one-line errors.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.errors import InvRenderError, ParameterError
from invrender.scene.builtin import sky_map, sky_spheres
from invrender.scene.camera import Camera

HIDDEN = {"type": "path", "hide_emitters": True}
MAP = (4, 8)


def view(azimuth: float) -> Camera:
    a = math.radians(azimuth)
    return Camera(origin=(4.2 * math.sin(a), 0.35, 4.2 * math.cos(a)), target=(0, -0.35, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller")


CAMERAS = [view(0.0), view(120.0), view(240.0)]


def scene(resolution=16, sky=None):
    return sky_spheres((resolution, resolution), MAP, subdivisions=2, sky=sky)


def test_matrix_times_map_is_the_render_of_the_same_seed():
    s = scene(12)
    tm = ir.lighting.transport_matrix(s, "sky", cameras=CAMERAS[:2], integrator=HIDDEN, spp=4, max_depth=3, seed=3)
    assert tm.halves[0].shape == (3, 2 * 144, MAP[0] * MAP[1])
    L = s.params["sky.emission"].detach()
    for v, cam in enumerate(CAMERAS[:2]):
        for half in (0, 1):
            img = ir.render(s.with_camera(cam), HIDDEN, spp=4, max_depth=3, seed=tm.seeds[v][half], sampler=tm.sampler, progress=False)
            mine = tm.images(L, half)[v]
            assert float(img.abs().max()) > 0.1
            torch.testing.assert_close(mine, img, rtol=1e-5, atol=1e-6)
    # another map of the same sampling: the matrix predicts its render as well
    other = L.flip(1).contiguous()
    img = ir.render(s.with_params({"sky.emission": other}).with_camera(CAMERAS[0]), HIDDEN, spp=4, max_depth=3, seed=tm.seeds[0][0], sampler=tm.sampler, progress=False, sampling_params={"sky.emission": L})
    torch.testing.assert_close(tm.images(other, 0)[0], img, rtol=1e-5, atol=1e-6)


def test_the_fused_bounce_renders_the_matrix_of_the_torch_bounce(monkeypatch):
    """The matrix's film takes the compiled bounce (which tells it each escaped ray's and emitter
    sample's direction, as the torch bounce does), also with hide_emitters: the same matrix."""
    from invrender.backends import kernels
    from invrender.core import fused

    s = scene(10, sky=sky_map(*MAP))
    traced = []
    trace = fused.trace
    monkeypatch.setattr(fused, "trace", lambda *a: traced.append(1) or trace(*a))
    for integrator in (HIDDEN, "path", {"type": "path", "strategy": "bsdf"}):
        kw = dict(cameras=CAMERAS[:2], integrator=integrator, spp=4, max_depth=3, seed=2, sampling_map=s.params["sky.emission"].detach())
        monkeypatch.delenv(kernels.ENV, raising=False)
        count = len(traced)
        mine = ir.lighting.transport_matrix(s, "sky", **kw)
        assert len(traced) > count  # the fused bounce ran
        monkeypatch.setenv(kernels.ENV, "steps")
        reference = ir.lighting.transport_matrix(s, "sky", **kw)
        for a, b in zip(mine.halves, reference.halves):
            assert float(b.abs().max()) > 0.05
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5 * float(b.abs().max()))


def test_halves_cross_product_is_unbiased_where_the_mean_gram_is_not():
    s = scene(6)
    cams = CAMERAS[:1]
    reference = ir.lighting.transport_matrix(s, "sky", cameras=cams, integrator=HIDDEN, spp=256, max_depth=2, seed=99)
    truth = sum(torch.trace(reference.halves[0][c].double().T @ reference.halves[1][c].double()) for c in range(3))
    cross, plain = [], []
    for seed in range(12):
        tm = ir.lighting.transport_matrix(s, "sky", cameras=cams, integrator=HIDDEN, spp=2, max_depth=2, seed=seed)
        A1, A2 = (a.double() for a in tm.halves)
        cross.append(sum(float(torch.trace(A1[c].T @ A2[c])) for c in range(3)))
        mean = 0.5 * (A1 + A2)
        plain.append(sum(float(torch.trace(mean[c].T @ mean[c])) for c in range(3)))
    cross, plain = torch.tensor(cross), torch.tensor(plain)
    spread = float(cross.std() / math.sqrt(len(cross)))
    assert abs(float(cross.mean()) - float(truth)) < 3 * spread + 0.02 * float(truth)
    assert float(plain.mean()) > 1.2 * float(truth)  # E^T E: the noise adds to every diagonal entry


def test_streamed_normal_equations_are_those_of_the_halves():
    s = scene(10)
    cams = CAMERAS[:2]
    targets = [torch.rand(10, 10, 3, generator=torch.Generator().manual_seed(v)) for v in range(2)]
    tm = ir.lighting.transport_matrix(s, "sky", cameras=cams, integrator=HIDDEN, spp=4, max_depth=3, seed=3)
    streamed = ir.lighting.normal_equations(s, "sky", targets, cameras=cams, integrator=HIDDEN, spp=4, max_depth=3, seed=3)
    A1, A2 = (a.double() for a in tm.halves)
    b = torch.cat([t.reshape(-1, 3) for t in targets]).double()
    for c in range(3):
        H = 0.5 * (A1[c].T @ A2[c] + A2[c].T @ A1[c])
        D = 0.25 * (A1[c] - A2[c]).T @ (A1[c] - A2[c])
        g = 0.5 * (A1[c] + A2[c]).T @ b[:, c]
        scale = float(H.abs().max())
        assert float((streamed.H(c) - H).abs().max()) < 1e-5 * scale
        assert float((streamed.D[c].double() - D).abs().max()) < 1e-5 * scale
        torch.testing.assert_close(streamed.g[c], g, rtol=1e-5, atol=1e-9)
        seen = b[(A1 + A2 != 0).any(0).any(1), c]  # pixels no path links to the map carry nothing
        assert 0 < seen.numel() < b.shape[0]
        assert abs(float(streamed.bb[c]) - float(seen.square().sum())) < 1e-6 * float(seen.square().sum())
    # the same seeds' kept matrix gives the same equations
    kept = ir.lighting.solve_map(tm, targets, weight=10.0, stderr=False).normal
    torch.testing.assert_close(kept.Gm, streamed.Gm)
    torch.testing.assert_close(kept.D, streamed.D)


def test_a_basis_matrix_is_the_texel_matrix_times_its_membership():
    s = scene(10)
    basis = ir.lighting.MapBasis.uniform(*MAP, 8)  # 2 x 2 blocks
    assert basis.n == 8 and not basis.is_texels
    texel = ir.lighting.transport_matrix(s, "sky", cameras=CAMERAS[:1], integrator=HIDDEN, spp=4, max_depth=3, seed=5)
    leaves = ir.lighting.transport_matrix(s, "sky", cameras=CAMERAS[:1], integrator=HIDDEN, spp=4, max_depth=3, seed=5, basis=basis)
    B = torch.from_numpy(basis.matrix().toarray()).float()
    for half in (0, 1):
        torch.testing.assert_close(leaves.halves[half], texel.halves[half] @ B, rtol=1e-4, atol=1e-6)
    # refined by a map with one bright texel: that texel's block is split first, down to the texel
    bright = torch.full((MAP[0] * MAP[1], 3), 0.1)
    bright[1 * MAP[1] + 5] = 100.0
    fine = basis.refined(bright, 11)
    assert fine.n == 11
    col = fine.columns()
    assert int((col == col[1 * MAP[1] + 5]).sum()) == 1  # the bright texel is a leaf of its own
    assert basis.refined(bright, 10).n == 8  # no split fits in 10


@pytest.fixture(scope="module")
def problem():
    """A 4 x 8 map from three 16 x 16 views (targets at 4096 spp: their noise well below the
    matrix's, which the discrepancy rule compares the residual with), the matrix at 2 x 32 spp,
    and a held-out view's matrix (64 spp) to measure relighting by."""
    truth = sky_map(*MAP)
    true_scene = scene(16, truth)
    targets = [ir.render(true_scene.with_camera(c), HIDDEN, spp=4096, max_depth=3, seed=100 + i, progress=False) for i, c in enumerate(CAMERAS)]
    start = scene(16, torch.ones(*MAP, 3))
    fit = ir.lighting.fit_map(start, targets, "sky", cameras=CAMERAS, integrator=HIDDEN, spp=32, max_depth=3)
    held = ir.lighting.transport_matrix(start, "sky", cameras=[view(60.0)], integrator=HIDDEN, spp=64, max_depth=3, seed=7)
    return truth, targets, fit, held


def relit_error(held, truth, texels) -> tuple[torch.Tensor, float]:
    true_img, relit = held.images(truth)[0], held.images(texels)[0]
    means = (relit.mean((0, 1)) - true_img.mean((0, 1))) / true_img.mean((0, 1))
    return means, float((relit - true_img).norm() / true_img.norm())


def test_fit_map_recovers_a_map_that_relights_a_held_out_view(problem, tmp_path):
    truth, _, fit, held = problem
    assert fit.rule == "discrepancy" and fit.texels.shape == (*MAP, 3)
    assert bool((fit.texels >= 0).all()) and bool(torch.isfinite(fit.stderr).all())
    means, rmse = relit_error(held, truth, fit.texels)
    assert float(means.abs().max()) < 0.02, means
    assert rmse < 0.08, rmse
    # the flat start relights far worse: the fit did the work
    flat = torch.full((*MAP, 3), float(truth.mean()))
    assert relit_error(held, truth, flat)[1] > 2 * rmse
    # the residual sits at the noise (the discrepancy principle; the targets' own noise above it),
    # and the report says so
    assert bool((fit.residual >= 0.95 * fit.noise).all()) and bool((fit.residual < 1.3 * fit.noise).all()), (fit.residual, fit.noise)
    assert "discrepancy" in fit.describe()
    # the bottom row (below the floor: no path reaches it) is left to the prior
    assert bool(fit.undetermined[-1].all())
    assert float(fit.resolution[-1].max()) < 0.1
    # the relighting product: the map and its standard errors as EXR, the identifiability as PNG
    paths = fit.write(tmp_path / "product")
    torch.testing.assert_close(ir.read_image(paths[0]), fit.texels)
    torch.testing.assert_close(ir.read_image(paths[1]), fit.stderr)
    from PIL import Image

    assert Image.open(paths[2]).size == (MAP[1], MAP[0])
    assert json.loads(paths[3].read_text())["rule"] == "discrepancy"


def test_the_weight_rule_is_within_1_5x_of_the_best_swept_weight(problem):
    truth, targets, fit, held = problem
    _, chosen = relit_error(held, truth, fit.texels)
    swept = []
    for e in torch.arange(-2.0, 4.01, 0.5).tolist():
        try:
            fixed = ir.lighting.solve_map(fit.normal, weight=10.0**e, stderr=False)
        except ParameterError:  # below the weight at which the regularized matrix is definite
            continue
        swept.append(relit_error(held, truth, fixed.texels)[1])
    assert len(swept) >= 4
    assert chosen <= 1.5 * min(swept), (chosen, swept)


def test_the_solution_is_optimal_over_every_unknown_and_the_search_is_short(problem):
    from invrender.inverse.map_fit import _Prior

    _, _, fit, _ = problem
    normal = fit.normal
    n = normal.n
    assert bool(fit.undetermined[-1].all())  # unreached texels: eliminated by the prior's extension
    # the full problem's gradient at the returned map (all unknowns, none eliminated): >= 0 where
    # a texel is at its bound 0, 0 where it is not (the KKT conditions of the non-negative solve)
    prior = _Prior(normal.basis, 1e-2, 1.0, np.ones(n, dtype=bool))
    for c in range(3):
        H = normal.H(c)
        lam_s = float(fit.weight[c]) * float(H.diagonal().sum()) / n
        x = fit.texels.reshape(-1, 3)[:, c].double()
        r = normal.g[c] + lam_s * torch.from_numpy(prior.pull(np.full(n, float(normal.flat[c]))))
        y = (H + lam_s * prior.Q) @ x - r
        tol = 1e-5 * float(r.abs().max())
        assert float(y.min()) > -tol
        assert float(y[x > 1e-6 * float(x.max())].abs().max()) < tol
    # Newton's search: a few factorizations (bisection to 0.05 decades took ~25 per channel), fewer
    # where the last channel's weight is the start, and
    # the weight is the discrepancy's root: residual below the noise a fifth of a decade lower, above it higher
    assert int(fit.evaluations.sum()) <= 16 and int(fit.evaluations[1:].max()) <= 4, fit.evaluations
    # (or, below, M no longer definite: the root often lies just above that weight)
    for factor, sign in ((10**-0.2, -1), (10**0.2, 1)):
        try:
            other = ir.lighting.solve_map(normal, weight=float(fit.weight[0]) * factor, stderr=False)
        except ParameterError as e:
            assert sign < 0 and "not positive definite" in str(e)
            continue
        excess = float(other.residual[0] ** 2 - other.noise[0] ** 2)
        assert excess * sign > 0, (factor, excess)


def test_a_sun_takes_a_second_round_sampled_by_the_first_in_a_refined_quadtree(monkeypatch):
    h, w = 8, 16
    truth = sky_map(h, w)
    lum = truth.mean(2)
    i, j = divmod(int(lum.flatten().argmax()), w)
    truth[i, j] *= 1000 * float(lum.median()) / float(lum[i, j])  # a one-texel sun 1000x the median
    true_scene = sky_spheres((12, 12), (h, w), subdivisions=2, sky=truth)
    targets = [ir.render(true_scene.with_camera(c), HIDDEN, spp=128, max_depth=2, seed=50 + k, progress=False) for k, c in enumerate(CAMERAS)]
    start = sky_spheres((12, 12), (h, w), subdivisions=2, sky=torch.ones(h, w, 3))
    from invrender.inverse import map_fit

    traced = []
    streamed = map_fit.normal_equations

    def spy(*args, **kw):
        traced.append(kw["spp"])
        return streamed(*args, **kw)

    monkeypatch.setattr(map_fit, "normal_equations", spy)
    fit = ir.lighting.fit_map(start, targets, "sky", cameras=CAMERAS, integrator=HIDDEN, spp=16, max_depth=2, unknowns=40)
    assert traced == [4, 16]  # a coarser basis: the first round is a pilot at spp // 4
    assert fit.rounds == 2 and fit.basis.n <= 40 and not fit.basis.is_texels  # 2 x 2 blocks (32), refined
    column = fit.basis.columns()
    assert int((column == column[i * w + j]).sum()) == 1  # the sun's texel is an unknown of its own
    bi, bj = divmod(int(fit.texels.mean(2).flatten().argmax()), w)
    assert abs(bi - i) <= 1 and min(abs(bj - j), w - abs(bj - j)) <= 1, ((bi, bj), (i, j))
    assert "2 rounds" in fit.describe() and f"{fit.basis.n} unknowns for {h * w} texels" in fit.describe()


def test_bad_inputs_are_one_line_errors(problem):
    truth, targets, fit, held = problem
    start = scene(16, torch.ones(*MAP, 3))
    with pytest.raises(ParameterError, match=r"needs .* GiB \(24 x pixels x unknowns .* \+ 72 x unknowns\^2") as e:
        ir.lighting.fit_map(start, targets, "sky", cameras=CAMERAS, integrator=HIDDEN, spp=4, memory_mb=0.1)
    assert "\n" not in str(e.value)
    with pytest.raises(ParameterError, match="3 target\\(s\\) but 2 camera\\(s\\)"):
        ir.lighting.fit_map(start, targets, "sky", cameras=CAMERAS[:2], spp=4)
    with pytest.raises(ParameterError, match="3 target\\(s\\) for a transport matrix of 1 view\\(s\\)"):
        ir.lighting.solve_map(held, targets)
    bad = targets[0].clone()
    bad[3, 4, 1] = float("nan")
    with pytest.raises(InvRenderError, match="NaN"):
        ir.lighting.fit_map(start, [bad, *targets[1:]], "sky", cameras=CAMERAS, spp=4)
    with pytest.raises(ParameterError, match="NaN"):
        ir.lighting.solve_map(held, [bad])
    with pytest.raises(ParameterError, match="no emitter 'skye'.*did you mean 'sky'"):
        ir.lighting.fit_map(start, targets, "skye", cameras=CAMERAS, spp=4)
    with pytest.raises(ParameterError, match="the unknowns' budget must be an integer >= 1, got 0"):
        ir.lighting.fit_map(start, targets, "sky", cameras=CAMERAS, spp=4, unknowns=0)
    with pytest.raises(ParameterError, match="rounds must be 1, 2 or 'auto', got 3"):
        ir.lighting.fit_map(start, targets, "sky", cameras=CAMERAS, spp=4, rounds=3)
    with pytest.raises(ParameterError, match="weight must be a number > 0"):
        ir.lighting.solve_map(fit.normal, weight=-1.0)
    with pytest.raises(ParameterError, match="rule must be one of discrepancy, gcv, got 'gvc' \\(did you mean 'gcv'\\?\\)"):
        ir.lighting.solve_map(fit.normal, rule="gvc")


def test_sphere_smoothness_is_the_dirichlet_energy():
    S = torch.from_numpy(ir.lighting.sphere_smoothness(5, 8).toarray())
    ones = torch.ones(40, dtype=torch.float64)
    assert float((S @ ones).abs().max()) < 1e-9  # a constant map has no gradient
    torch.testing.assert_close(S, S.T)
    assert float(torch.linalg.eigvalsh(S)[0]) > -1e-9
    # a map varying in longitude only wraps: cos(phi) costs the same wherever the seam lies
    phi = (torch.arange(8, dtype=torch.float64) + 0.5) * (2 * math.pi / 8)
    a = torch.cos(phi).repeat(5)
    b = torch.cos(phi + 2 * math.pi / 8).repeat(5)
    assert abs(float(a @ S @ a) - float(b @ S @ b)) < 1e-9 * float(a @ S @ a)


def test_sparse_quadratic_is_optimal_and_the_sparsity_prior_shrinks_the_haar_details(problem):
    """The L1 prior on the Haar details (ADMM): with mu = 0 the bounded solve; otherwise no
    feasible move from its answer lowers the objective (convex: optimal), and a larger weight
    leaves the map's details smaller (their L1 norm falls) and its top grid alone."""
    from invrender.estimators.map_basis import MapBasis
    from invrender.inverse.map_fit import bounded_quadratic, sparse_quadratic

    basis = MapBasis.of_texels(4, 8)
    C, details = basis.haar()
    gen = torch.Generator().manual_seed(3)
    A = torch.rand(40, 32, generator=gen, dtype=torch.float64)
    M = A.T @ A + 0.1 * torch.eye(32, dtype=torch.float64)
    r = A.T @ torch.rand(40, generator=gen, dtype=torch.float64) * 3
    smooth = bounded_quadratic(M, r, torch.linalg.cholesky(M))
    torch.testing.assert_close(sparse_quadratic(M, r, C, details, 0.0, smooth), smooth, rtol=1e-6, atol=1e-8)
    d = torch.from_numpy(details)

    def F(x, mu):
        c = torch.from_numpy(C @ x.numpy())
        return float(x @ M @ x - 2 * r @ x + 2 * mu * c[d].abs().sum())

    mu = 0.5
    x = sparse_quadratic(M, r, C, details, mu, smooth, tol=1e-8, iterations=5000)
    assert bool((x >= 0).all()) and F(x, mu) < F(smooth, mu) - 1e-6
    for _ in range(200):
        y = (x + 1e-3 * torch.randn(32, generator=gen, dtype=torch.float64) * x.abs().max()).clamp_min(0)
        assert F(y, mu) >= F(x, mu) - 1e-7 * abs(F(x, mu))
    # in a fit: the details' L1 norm falls as the weight grows
    _, _, fit, _ = problem
    norms = []
    for sparsity in (0.0, 0.3, 3.0):
        got = ir.lighting.solve_map(fit.normal, sparsity=sparsity, stderr=False)
        norms.append(float(torch.from_numpy(C @ got.texels.reshape(-1, 3).double().numpy())[d].abs().sum()))
    assert norms[0] > norms[1] > norms[2], norms
    with pytest.raises(ParameterError, match="sparsity must be a finite number >= 0, got -1"):
        ir.lighting.solve_map(fit.normal, sparsity=-1)
    with pytest.raises(ParameterError, match="the Haar basis needs a map whose height and width are powers of 2, got 5 x 8"):
        MapBasis.of_texels(5, 8).haar()


def test_fit_map_refuses_bad_solve_settings_before_any_render(monkeypatch):
    from invrender.inverse import map_fit

    monkeypatch.setattr(map_fit, "normal_equations", lambda *a, **k: pytest.fail("rendered before refusing"))
    odd = scene(16, torch.ones(5, 8, 3))
    targets = [torch.zeros(16, 16, 3)] * 3
    for kw, message in (({"sparsity": 0.5}, "powers of 2, got 5 x 8"), ({"sparsity": float("nan")}, "sparsity must be a finite number >= 0, got nan"), ({"smoothness": -1}, "smoothness must be a finite number >= 0")):
        with pytest.raises(ParameterError, match=message) as e:
            ir.lighting.fit_map(odd, targets, "sky", cameras=CAMERAS, integrator=HIDDEN, spp=2, **kw)
        assert "\n" not in str(e.value)
