"""The inference pipeline, in the order data flows through it.

``data`` (ranked demonstrations) -> ``constraints`` (candidate features and parametric families)
-> ``preferences`` (groups, margins, pair protocols) -> ``likelihood`` (paper Eq. 7 and the grouped
likelihood; compiled kernels in ``likelihood_kernels``) with ``priors`` -> ``samplers`` (MCMC kernels and
the chain driver) -> ``results`` (:class:`~pbicrl.inference.results.Posterior`, draws in ``draws``).
``synthetic`` builds problems with a known answer.
"""
