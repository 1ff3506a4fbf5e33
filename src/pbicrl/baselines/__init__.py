"""Baselines that pbicrl is compared with (optional extra ``rl``: PyTorch and Gymnasium).

* :mod:`pbicrl.baselines.icl` - Inverse Constraint Learning (Gaurav et al. 2022), the method the PBICRL
  paper compares with in its Tables I and II;
* :mod:`pbicrl.baselines.ppo_lagrangian` - the PPO-Lagrangian constrained RL solver ICL alternates with.

Nothing is imported here: the submodules need torch and gymnasium (``pip install "pbicrl[rl,envs]"``).
"""

__all__: list[str] = []
