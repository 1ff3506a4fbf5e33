"""MCMC samplers: PBICRL (flip-and-draw), the paper's Algorithm 1, and BPL (Algorithm 3).

``build_kernel(likelihood, settings)`` binds settings into a :class:`Kernel` with pure
``init(rng) -> ChainState`` and ``step(rng, state) -> (ChainState, StepInfo)``; :func:`sample` is the one
driver for several chains and many draws.
"""

from pbicrl.inference.samplers.bundles import Adaptation, MapTracker, Position
from pbicrl.inference.samplers.driver import run_chain, sample
from pbicrl.inference.samplers.kernels import METHODS, ChainState, Kernel, SamplerSettings, StepInfo, build_kernel

__all__ = ["sample", "run_chain", "build_kernel", "Kernel", "SamplerSettings", "ChainState", "StepInfo", "METHODS",
           "Position", "Adaptation", "MapTracker"]
