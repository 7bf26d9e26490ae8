"""Light transport: sampler, intersection, BSDF, lights, integrators, film, render."""
