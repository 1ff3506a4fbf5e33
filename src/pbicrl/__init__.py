"""pbicrl: Bayesian constraint inference from ranked demonstrations.

Architecture (one module per concept)::

    data -> preferences -> likelihood -> samplers -> results
                 (synthetic problems, envs, demonstrators, experiments and baselines beside it;
                  the CLI on top)
"""

from pbicrl.data import Dataset, DatasetError, load_dataset

__version__ = "0.1.0"

__all__ = ["Dataset", "DatasetError", "load_dataset", "__version__"]
