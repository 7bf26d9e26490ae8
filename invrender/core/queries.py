"""The ray queries an integrator sees (``ctx.accel``): the closest hits of a batch of rays
(:class:`Hits`, or compacted to the rays that hit: :class:`FoundHits`) and a wrapper that answers the same queries again from a first pass's answers
(:class:`RepeatedQueries`). The intersection backends implement them
(:mod:`invrender.backends.accel`); integrators name them through the core, never a backend."""

from invrender.backends.accel import FoundHits, Hits, RepeatedQueries

__all__ = ["FoundHits", "Hits", "RepeatedQueries"]
