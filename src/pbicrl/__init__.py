"""pbicrl: Bayesian constraint inference from ranked demonstrations.

Architecture (one folder per stage)::

    inference/   data -> constraints -> preferences -> likelihood (+ priors) -> samplers -> posterior
                 (imports nothing from analysis/, io/ or cli/)
    analysis/    identify, diagnostics, check, calibration, metrics, margins, suggest, export, plots, report
    io/          run directories (load_run, save_run), CSV/Parquet and Minari import
    envs/ demonstrators/ baselines/ experiments/ ui/   beside it
    cli/         the command line on top; api.py, config.py: the Python entry points

Quick start::

    import pbicrl
    ds = pbicrl.load_dataset("demos.npz")          # grouped trajectories, group 1 = best
    post = pbicrl.infer(ds, margins=[0.0, 2.9])     # PBICRL posterior, 4 chains
    print(post.table())
    post.save("runs/demo")
    post = pbicrl.load_run("runs/demo")            # the same Posterior back
"""

from pbicrl import _moved
from pbicrl._version import __version__
from pbicrl.api import infer, infer_from_config, load_run
from pbicrl.config import InferConfig
from pbicrl.inference.data import Dataset, DatasetError, list_shipped_datasets, load_dataset, resolve_dataset_path
from pbicrl.errors import PbicrlWarning
from pbicrl.analysis.identify import Identification, identify
from pbicrl.inference.likelihood import PreferenceLikelihood, log_likelihood
from pbicrl.inference.preferences import Margins, PreferenceError, Preferences
from pbicrl.inference.priors import IndicatorPrior, PriorError, WeightPrior
from pbicrl.inference.posterior import Posterior
from pbicrl.inference.samplers import SamplerSettings, build_kernel, sample

_moved.install()

__all__ = [
    "Dataset", "DatasetError", "load_dataset", "resolve_dataset_path", "list_shipped_datasets",
    "PbicrlWarning", "identify", "Identification", "Margins", "Preferences", "PreferenceError",
    "PreferenceLikelihood", "log_likelihood", "WeightPrior", "IndicatorPrior", "PriorError",
    "SamplerSettings", "build_kernel", "sample", "Posterior", "infer", "infer_from_config", "InferConfig", "load_run",
    "__version__",
]
