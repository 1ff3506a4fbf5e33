"""Inverse Constraint Learning (ICL; Gaurav, Rezaee, Liu, Poupart 2022, arXiv 2206.01311), our implementation.

ICL learns a soft constraint :math:`c(s) \\in [0, 1]` from *expert* demonstrations only, given the nominal
reward, by alternating for ``rounds`` outer rounds:

(a) **constrained RL** under the current constraint: PPO-Lagrangian
    (:class:`pbicrl.baselines.ppo_lagrangian.PPOLagrangian`) maximises the nominal return subject to
    :math:`J_c(\\pi) = \\mathbb{E}[\\sum_t \\gamma^t c(s_{t+1})] \\le \\beta`; its multiplier is updated from the
    expected discounted *cost* (the authors' public code uses the episode reward there; we follow the
    Lagrangian method);
(b) **constraint adjustment**: with trajectories sampled from every policy so far
    :math:`\\pi_1..\\pi_i`, minimise

    .. math:: L(c) = -\\sum_j w_j \\hat J_c(\\pi_j) + \\lambda_h \\max(0, \\hat J_c(\\pi_E) - \\beta)

    so that the learned policies' trajectories become costly while the expert stays within budget. The
    mixture weights :math:`w_j` favour the policies least like the expert: :math:`w_j \\propto` the total
    variation distance between the discounted visitation histogram ("accrual") of :math:`\\pi_j` and the
    expert's over the constrained coordinate (:func:`mixture_weights`).

The constraint function is a small MLP with a sigmoid output over the constrained coordinate only (the
x-position for HalfCheetah/Ant, the position for the point mass), its input standardised with the expert
data's mean and spread. For a 1-D coordinate, the learned constraint location :math:`\\hat\\vartheta` is read off
where :math:`c` first reaches 0.5 (:func:`constraint_location`) and scored with
:func:`pbicrl.analysis.metrics.cmse_location`; :func:`pbicrl.analysis.metrics.cmse_grid` compares :math:`c` with the true
indicator over a grid.

Budgets: :func:`icl_preset` (``"smoke"``: well under a minute on the point mass; ``"default"``: one
HalfCheetah seed in roughly 45 minutes on a 2-core CPU; ``"paper"``: larger, for bigger machines). Runs are
resumable: :func:`run_icl` checkpoints into its directory (every ``checkpoint_every`` environment steps and
after every round) and continues from there when called again; SIGTERM/SIGINT checkpoint and stop.
Checkpoints hold tensors and plain Python values only and are read with ``torch.load(weights_only=True)``: a
``checkpoint.pt`` put into a run directory by someone else cannot run code when the run resumes.

Needs torch and gymnasium (``pip install "pbicrl[rl,envs]"``).

The package, one module per concern: :mod:`~.presets` (settings and budgets), :mod:`~.environments`,
:mod:`~.network` (the constraint MLP), :mod:`~.losses` (objective, mixture weights, location),
:mod:`~.checkpoint`, :mod:`~.run` (:func:`run_icl`) and :mod:`~.task` (the ``reproduce-icl`` task kind). Every
public name is importable from here. Stopping on SIGTERM/SIGINT, the progress log and the recorded versions are
:mod:`pbicrl.baselines.session`, shared with ``train-safe`` and the SAC demonstrators.
"""

from __future__ import annotations

from pbicrl.baselines.icl.checkpoint import load_checkpoint, save_checkpoint, write_json_file
from pbicrl.baselines.icl.environments import (
    ICRL_ICL_ENVS,
    ICLEnv,
    ICRLFactory,
    expert_coordinates,
    hide_true_cost,
    icl_env,
    icrl_coord,
    point_mass_expert_demos,
)
from pbicrl.baselines.icl.losses import accrual, constraint_location, constraint_loss, discount_matrix, mixture_weights
from pbicrl.baselines.icl.network import ConstraintNet
from pbicrl.baselines.icl.presets import ENVS, PRESETS, ICLConfig, icl_preset
from pbicrl.baselines.icl.run import run_icl
from pbicrl.baselines.icl.task import run_icl_task

__all__ = [
    "ENVS",
    "PRESETS",
    "ConstraintNet",
    "ICLConfig",
    "ICLEnv",
    "ICRLFactory",
    "ICRL_ICL_ENVS",
    "accrual",
    "constraint_location",
    "constraint_loss",
    "discount_matrix",
    "expert_coordinates",
    "hide_true_cost",
    "icl_env",
    "icl_preset",
    "icrl_coord",
    "mixture_weights",
    "point_mass_expert_demos",
    "run_icl",
    "run_icl_task",
    "save_checkpoint",
    "write_json_file",
    "load_checkpoint",
]

# The names of pbicrl 0.1 (tests and scripts import them from here).
_load_checkpoint = load_checkpoint
_torch_save = save_checkpoint
_write_json = write_json_file
