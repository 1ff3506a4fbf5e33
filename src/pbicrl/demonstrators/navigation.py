"""SAC demonstrators and ranked demonstrations for the point mass and Fetch-Reach.

Two policies per environment (paper Sec. V-A/V-B): a *good* one trained on the true
reward (penalties included) and a *violating* one trained on the nominal reward (no
penalties, so it cuts through the constraint regions).  Two ways to turn them into a
three-group ranked dataset; both label every trajectory from its states
(:meth:`pbicrl.envs.regions.NavigationTask.group`: G3 if it entered red, else G2 if it
entered orange, else G1):

* :func:`generate_paper_protocol_demos` (the paper's design, used for the shipped data):
  every rollout starts from the environment's one start distribution and is made by the
  good policy with probability ``p_good``, else by the violating one; the group is the
  worst region the trajectory entered, whichever policy made it.  All rollouts are kept
  except those that do not reach the goal (counted in the report); it stops once every
  group holds at least ``n_per_group``.  :func:`group_feature_balance` measures how far
  the groups differ in their nominal features (standardised mean differences).
* :func:`generate_navigation_demos` (earlier design): ``G1`` = good policy, ``G2``/``G3`` =
  violating policy, each filled to exactly ``n_per_group``.  Its groups differ in nominal
  behaviour (the policies move differently), which a ranking model can exploit.

Training settings per environment are in :data:`NAV_ENVS` (see :class:`NavEnvSpec` for why
they depart from the paper's SAC table).

Each stored trajectory holds the visited states ``s_0 .. s_T`` (start included) and their
features; actions are not stored in the ``.npz`` (there are only ``T`` of them), but the
Minari export (:mod:`pbicrl.envs.minari_io`) keeps them.

The code lives in modules by concern, beside this one: :mod:`~pbicrl.demonstrators.nav_envs` (settings,
environments), :mod:`~pbicrl.demonstrators.nav_training` (SAC training), :mod:`~pbicrl.demonstrators.nav_rollouts`
(rollouts, the earlier design), :mod:`~pbicrl.demonstrators.nav_protocol` (the paper's design) and
:mod:`~pbicrl.demonstrators.nav_plots`; every public name is importable from here as before.
"""

from __future__ import annotations

from pbicrl.demonstrators.nav_envs import NAV_ENVS, NavEnvSpec, make_nav_env
from pbicrl.demonstrators.nav_plots import plot_navigation_demos
from pbicrl.demonstrators.nav_protocol import PAPER_PROTOCOL, generate_paper_protocol_demos, group_feature_balance
from pbicrl.demonstrators.nav_rollouts import Episode, generate_navigation_demos, rollout_episodes
from pbicrl.demonstrators.nav_training import cost_to_go_potential, relabelled_warm_start, train_nav_policy

__all__ = [
    "NAV_ENVS",
    "Episode",
    "NavEnvSpec",
    "PAPER_PROTOCOL",
    "generate_navigation_demos",
    "generate_paper_protocol_demos",
    "group_feature_balance",
    "make_nav_env",
    "plot_navigation_demos",
    "relabelled_warm_start",
    "rollout_episodes",
    "train_nav_policy",
    "cost_to_go_potential",
]
