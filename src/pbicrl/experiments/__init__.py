"""Experiments at scale: runs as tasks (:mod:`~pbicrl.experiments.tasks`), executed on a local process pool,
in-process or on Ray (:mod:`~pbicrl.experiments.executors`), expanded from a grid and resumed
(:mod:`~pbicrl.experiments.sweep`).

Kept light: importing this package imports no submodule (Ray in particular is imported only when used).
"""

__all__: list[str] = []
