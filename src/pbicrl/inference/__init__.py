"""The inference pipeline, in the order data flows through it.

``data`` (ranked demonstrations) -> ``constraints`` (candidate features and parametric families)
-> ``preferences`` (groups, margins, pair protocols) -> ``likelihood`` (paper Eq. 7 and the grouped
likelihood; compiled kernels in ``likelihood_kernels``) with ``priors`` -> ``samplers`` (MCMC kernels and
the chain driver) -> ``posterior`` (:class:`~pbicrl.inference.posterior.Posterior`: the draws, ``draws``, and
their summaries, ``summary``, ``prior_driven``, ``posterior_warnings``). Nothing here imports ``analysis``, ``io``
or ``cli`` (``tests/test_architecture.py``): files are :mod:`pbicrl.io.runs`, tables :mod:`pbicrl.analysis.report`.
``synthetic`` builds problems with a known answer.
"""
