"""Radiosity's figures (docs/radiosity.md): solver accuracy against the sphere interior's closed form,
form-factor error, the discretization bias against the path tracer on the Cornell box (images and
gradients), and the random walks against the direct solve.

    python bench/radiosity.py [--parts solver,squares,sphere,cornell,walks] [--patches 64,256,1024,4096]
                              [--rays 256] [--seeds 4] [--spp 64] [--final-gather]

Run from the repository root (it reuses the scenes of tests/radiosity/conftest.py). ``cornell`` at
4096 patches takes minutes.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

import invrender as ir
from invrender.scene.scene import build_scene
from invrender.scene.shapes import primitive, rotate, scale, translate
from invrender.backends.accel import make_intersector
from invrender.radiosity_solver import FormFactorSettings, SolverSettings, form_factors, mesh_patches, neumann_ulam, solve

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root, for the tests' scenes
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _measure import Results, add_json_option  # noqa: E402
from tests.radiosity.conftest import (
    NORTH_EPS,
    NORTH_RHO,
    SOUTH_EPS,
    SOUTH_RHO,
    area_fractions,
    hemispheres,
    sphere_closed_form,
    sphere_system,
)

CORNELL_PARAMS = ["white.reflectance", "red.reflectance", "green.reflectance", "light.emission"]


def solver_part(record: Results) -> None:
    print("## solver: sphere interior, exact F_ij = a_j, non-uniform rho and E")
    rows = record.table("solver: sphere interior, exact F_ij = a_j, non-uniform rho and E, against the closed form",
                        ["patches", "method", "max rel error", "iterations", "ms"])
    for n in (50, 400):
        a, F, rho, E = sphere_system(n=n)
        expected = sphere_closed_form(a, rho, E)
        for method in ("direct", "jacobi", "gauss_seidel", "neumann"):
            t = time.perf_counter()
            B, report = solve(F, rho, E, SolverSettings(method=method))
            dt = time.perf_counter() - t
            err = float(((B - expected).abs() / expected).max())
            print(f"n={n:4d} {method:13s} max rel error {err:.2e}  iterations {report.iterations:3d}  {dt * 1e3:7.1f} ms")
            rows.append([n, method, f"{err:.2e}", report.iterations, round(dt * 1e3, 1)])
    a, F, rho, E = sphere_system(n=20)
    J_rho, J_E = torch.autograd.functional.jacobian(lambda r, e: solve(F, r, e)[0], (rho, E))
    rho_bar, E_bar = (a[:, None] * rho).sum(0), (a[:, None] * E).sum(0)
    eye = torch.eye(20, dtype=torch.float64)
    worst = 0.0
    for c in range(3):
        dE = eye + rho[:, c, None] * a[None] / (1 - rho_bar[c])
        drho = eye * E_bar[c] / (1 - rho_bar[c]) + rho[:, c, None] * E_bar[c] * a[None] / (1 - rho_bar[c]) ** 2
        worst = max(worst, float((J_E[:, c, :, c] - dE).abs().max() / dE.abs().max()), float((J_rho[:, c, :, c] - drho).abs().max() / drho.abs().max()))
    print(f"adjoint gradients vs closed-form derivatives (n=20): max rel error {worst:.2e}")
    rows.append([20, "adjoint gradients vs closed-form derivatives", f"{worst:.2e}", "", ""])


def squares_part(seeds: int, record: Results) -> None:
    print("## unit squares (Howell: parallel 0.19982, perpendicular 0.20004), one patch per triangle")
    rows = record.table(f"form factors of unit squares against Howell's (parallel 0.19982, perpendicular 0.20004), {seeds} seeds",
                        ["case", "rays per side", "relative errors", "rms", "stated stderr"])
    cases = [("parallel", translate([0.5, 0.5, 1]) @ rotate([1, 0, 0], 180), 0.19982), ("perpendicular", translate([0, 0.5, 0.5]) @ rotate([0, 1, 0], 90), 0.20004)]
    for name, second, exact in cases:
        a = primitive("rectangle", "a").transformed(translate([0.5, 0.5, 0]) @ scale(0.5))
        b = primitive("rectangle", "b").transformed(second @ scale(0.5))
        scene = build_scene([a, b], {"a": 0.5, "b": 0.5}, {}, ir.Camera(), (4, 4))
        patches = mesh_patches(scene.triangles, subdivision=1)
        side = torch.arange(2 * patches.count)
        material = scene.triangles.material[patches.tri[side // 2]]
        front = side % 2 == 0
        for rays in (4096, 16384, 65536, 262144):
            errs, ses = [], []
            for seed in range(seeds):
                factors = form_factors(patches, make_intersector(scene.triangles), FormFactorSettings(rays=rays, batches=8, seed=seed), 1e-5)
                F, se = factors.group(front & (material == 0), front & (material == 1))
                errs.append(F / exact - 1)
                ses.append(se / exact)
            rms = (sum(e * e for e in errs) / seeds) ** 0.5
            print(f"{name:13s} rays/side {rays:6d}: rel errors {' '.join(f'{e:+.4%}' for e in errs)}  rms {rms:.3%}  stated stderr {sum(ses) / seeds:.3%}")
            rows.append([name, rays, " ".join(f"{e:+.4%}" for e in errs), f"{rms:.3%}", f"{sum(ses) / seeds:.3%}"])


def sphere_part(spp: int, record: Results) -> None:
    print("## tessellated sphere: south -> north form factor minus the area fraction a_north")
    rows = record.table("tessellated sphere: south -> north form factor minus the area fraction a_north", ["level", "triangles", "F - a_north", "stderr"])
    for level in (0, 1, 2, 3):
        scene = hemispheres(level)
        patches = mesh_patches(scene.triangles, subdivision=1)
        factors = form_factors(patches, make_intersector(scene.triangles), FormFactorSettings(rays=2048, batches=8), 1e-5)
        side = torch.arange(2 * patches.count)
        material = scene.triangles.material[patches.tri[side // 2]]
        front = side % 2 == 0
        F, se = factors.group(front & (material == 1), front & (material == 0))
        print(f"level {level} ({scene.triangles.count:5d} triangles): {F - float(area_fractions(scene)[0]):+.5f} +- {se:.5f}")
        rows.append([level, scene.triangles.count, f"{F - float(area_fractions(scene)[0]):+.5f}", f"{se:.5f}"])
    print("## hemispheres (level 2, 16x16): renders against the closed form, same camera samples")
    rows = record.table(f"two hemispheres (level 2, 16x16, {spp} spp): renders against the closed form, same camera samples",
                        ["seed", "path - closed (R G B)", "z (R G B)", "radiosity - closed (R G B)"])
    scene = hemispheres(2)
    marker = hemispheres(2, rho=((0, 0, 0), (0, 0, 0)), eps=((1, 0, 0), (0, 1, 0)))
    rho = torch.tensor([NORTH_RHO, SOUTH_RHO], dtype=torch.float64)
    E = torch.tensor([NORTH_EPS, SOUTH_EPS], dtype=torch.float64)
    L = sphere_closed_form(area_fractions(scene), rho, E)
    for seed in range(3):
        share = ir.render(marker, "path", spp=spp, max_depth=1, seed=seed, progress=False).double()
        closed = share[..., 0:1] * L[0] + share[..., 1:2] * L[1]
        path = ir.render(scene, "path", spp=spp, max_depth=-1, seed=seed, progress=False).double()
        rad = ir.render(scene, "radiosity", spp=spp, seed=seed, subdivision=1, progress=False).double()
        d = (path - closed).reshape(-1, 3)
        mean = closed.mean((0, 1))
        z = d.mean(0) / (d.std(0) / d.shape[0] ** 0.5)
        print(
            f"seed {seed}: path - closed {_pct(d.mean(0) / mean)} (z {' '.join(f'{v:+.1f}' for v in z.tolist())}); "
            f"radiosity - closed {_pct((rad - closed).mean((0, 1)) / mean)}"
        )
        rows.append([seed, _pct(d.mean(0) / mean), " ".join(f"{v:+.1f}" for v in z.tolist()), _pct((rad - closed).mean((0, 1)) / mean)])


def cornell_part(patch_counts: list[int], rays: int, seeds: int, spp: int, final_gather: bool, record: Results) -> None:
    print(f"## Cornell box 32x32, {spp} spp x {seeds} seeds, paired: radiosity vs path (unbounded), relative differences")
    rows = record.table(f"Cornell box 32x32, {spp} spp x {seeds} seeds, paired: radiosity vs path (unbounded), relative differences",
                        ["patches", "unknowns", "rays", "final gather", "solve s", "image means (R G B)", "+-", "gradients (12 scalars)"])
    scene = ir.load_scene("cornell_box", resolution=(32, 32))
    for n in CORNELL_PARAMS:
        scene.params[n].requires_grad_(True)

    def run(**options):
        means, grads = [], []
        for seed in range(seeds):
            for n in CORNELL_PARAMS:
                scene.params[n].grad = None
            img = ir.render(scene, spp=spp, seed=seed, progress=False, **options)
            img.mean().backward()
            means.append(img.detach().double().mean((0, 1)))
            grads.append(torch.cat([scene.params[n].grad.double() for n in CORNELL_PARAMS]))
        return torch.stack(means), torch.stack(grads)

    path_means, path_grads = run(integrator="path", max_depth=-1)
    print(f"path channel means {path_means.mean(0).tolist()}")
    for count in patch_counts:
        for gather in (False, True) if final_gather else (False,):
            t = time.perf_counter()
            with torch.no_grad():
                sol = ir.radiosity(scene, patches=count, rays=rays)
            solve_time = time.perf_counter() - t
            means, grads = run(integrator="radiosity", patches=count, rays=rays, final_gather=gather)
            dm, dg = means - path_means, grads - path_grads
            rel_m, se_m = dm.mean(0) / path_means.mean(0), dm.std(0) / seeds**0.5 / path_means.mean(0)
            rel_g, se_g = dg.mean(0) / path_grads.mean(0), dg.std(0) / seeds**0.5 / path_grads.mean(0).abs()
            print(
                f"patches {sol.patches.count:5d} (target {count}), unknowns {sol.sides.shape[0]:5d}, rays {rays}, final_gather {gather}: "
                f"solve {solve_time:.2f} s ({sol.report.method})\n  image means {_pct(rel_m)} +- {_pct(se_m)}\n"
                f"  gradients   {_pct(rel_g)}\n           +- {_pct(se_g)}"
            )
            rows.append([sol.patches.count, sol.sides.shape[0], rays, gather, round(solve_time, 2), _pct(rel_m), _pct(se_m), _pct(rel_g)])


def walks_part(record: Results) -> None:
    print("## random walks on the sphere interior (n=12, exact F) and the coarse Cornell box: z = (walk - solve) / stderr")
    rows = record.table("Neumann-Ulam random walks against the direct solve: z = (walk - solve) / stderr",
                        ["system", "estimator", "transition", "max |z|", "mean z (R G B)", "rel stderr", "s"])
    a, F, rho, E = sphere_system(n=12, seed=2)
    M, x = rho.T[:, :, None] * F[None], sphere_closed_form(a, rho, E).T
    for estimator in ("collision", "absorption"):
        for transition in ("analog", "uniform"):
            t = time.perf_counter()
            est = neumann_ulam(M, E.T.contiguous(), transition, estimator, walks=3000, seed=3)
            z = (est.mean - x) / est.stderr
            agg = ((a * est.mean).sum(1) - (a * x).sum(1)) / ((a * est.stderr) ** 2).sum(1).sqrt()
            print(
                f"sphere {estimator:10s} {transition:8s}: max |z| {float(z.abs().max()):.2f} (36 values), B_bar z {' '.join(f'{v:+.2f}' for v in agg.tolist())}, "
                f"rel stderr {float((est.stderr / x).mean()):.2%}, variance radius {' '.join(f'{v:.3f}' for v in est.variance_radius.tolist())}, {time.perf_counter() - t:.2f} s"
            )
            rows.append(["sphere (36 values)", estimator, transition, f"{float(z.abs().max()):.2f}", " ".join(f"{v:+.2f}" for v in agg.tolist()),
                         f"{float((est.stderr / x).mean()):.2%}", round(time.perf_counter() - t, 2)])
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    sol = ir.radiosity(scene, subdivision=1, rays=256)
    B = sol.B.detach().T
    w = sol.area.double() / sol.area.double().sum()
    for estimator in ("collision", "absorption"):
        est = sol.random_walk(estimator, walks=2000, seed=1)
        z = ((w * est.mean).sum(1) - (w * B).sum(1)) / ((w * est.stderr) ** 2).sum(1).sqrt()
        print(f"cornell ({B.shape[1]} unknowns) {estimator}: area-weighted mean z {' '.join(f'{v:+.2f}' for v in z.tolist())}")
        rows.append([f"Cornell box ({B.shape[1]} unknowns)", estimator, "analog", "", " ".join(f"{v:+.2f}" for v in z.tolist()), "", ""])
    try:
        sol.random_walk(transition="uniform")
    except ir.ParameterError as err:
        print(f"cornell, uniform transitions refused: {err}")
        record.note(f"Cornell box, uniform transitions refused: {err}")
    n = M.shape[1]
    P = torch.full((n, n), 0.9 / n, dtype=torch.float64)
    P[:, 0] = 1e-4
    P = P / P.sum(1, keepdim=True) * 0.9
    try:
        neumann_ulam(M, E.T.contiguous(), P)
    except ir.ParameterError as err:
        print(f"refused: {err}")
        record.note(f"sphere, a transition matrix with a near-zero column refused: {err}")


def _pct(x: torch.Tensor) -> str:
    return " ".join(f"{float(v):+.2%}" for v in x)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", default="solver,squares,sphere,cornell,walks")
    parser.add_argument("--patches", default="64,256,1024,4096", help="Cornell box target patch counts")
    parser.add_argument("--rays", type=int, default=256, help="form-factor rays per patch side (Cornell box)")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--final-gather", action="store_true", help="also the Cornell box with final gather")
    add_json_option(parser)
    args = parser.parse_args()
    torch.set_num_threads(2)
    parts = args.parts.split(",")
    record = Results("radiosity", "Radiosity: solver accuracy, form factors, bias against the path tracer, random walks")
    if "solver" in parts:
        solver_part(record)
    if "squares" in parts:
        squares_part(3, record)
    if "sphere" in parts:
        sphere_part(args.spp, record)
    if "cornell" in parts:
        cornell_part([int(p) for p in args.patches.split(",")], args.rays, args.seeds, args.spp, args.final_gather, record)
    if "walks" in parts:
        walks_part(record)
    record.write(args.json)


if __name__ == "__main__":
    main()
