"""pbicrl: Bayesian constraint inference from ranked demonstrations.

Architecture (one module per concept)::

    data -> preferences -> likelihood -> samplers -> results
    (priors, synthetic problems; envs, demonstrators, experiments and baselines beside it; the CLI on top)

Quick start::

    import pbicrl
    ds = pbicrl.load_dataset("demos.npz")          # grouped trajectories, group 1 = best
    post = pbicrl.infer(ds, margins=[0.0, 2.9])     # PBICRL posterior, 4 chains
    print(post.table())
    post.save("runs/demo")
    post = pbicrl.load_run("runs/demo")            # the same Posterior back
"""

from pbicrl._version import __version__
from pbicrl.api import infer, infer_from_config, load_run
from pbicrl.config import InferConfig
from pbicrl.data import Dataset, DatasetError, list_shipped_datasets, load_dataset, resolve_dataset_path
from pbicrl.errors import PbicrlWarning
from pbicrl.identify import Identification, identify
from pbicrl.likelihood import PreferenceLikelihood, log_likelihood
from pbicrl.preferences import Margins, PreferenceError, Preferences
from pbicrl.priors import IndicatorPrior, PriorError, WeightPrior
from pbicrl.results import Posterior
from pbicrl.samplers import SamplerSettings, build_kernel, sample

__all__ = [
    "Dataset", "DatasetError", "load_dataset", "resolve_dataset_path", "list_shipped_datasets",
    "PbicrlWarning", "identify", "Identification", "Margins", "Preferences", "PreferenceError",
    "PreferenceLikelihood", "log_likelihood", "WeightPrior", "IndicatorPrior", "PriorError",
    "SamplerSettings", "build_kernel", "sample", "Posterior", "infer", "infer_from_config", "InferConfig", "load_run",
    "__version__",
]
