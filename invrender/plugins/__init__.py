"""The plugins, one module each and one home per kind: BSDFs (``bsdfs/``), emitters
(``emitters/``), reconstruction filters (``filters/``) and integrators (``integrators/``). Each registers itself in
:mod:`invrender.registry`; a plugin implements an interface of :mod:`invrender.core` and never
imports a backend."""
