"""Light transport: the chunked driver, counter-based sampler, intersection backends, BSDFs
(``bsdfs/``), emitter sampling, integrators (``integrators/``), film. Knows no estimator: path
replay and decorrelated gradients live in :mod:`invrender.diff`."""
