"""The core every integrator uses: the driver, sampler, film, context and the bounce."""
