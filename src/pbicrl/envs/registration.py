"""Gymnasium ids for the pbicrl navigation environments.

:func:`register_envs` registers (idempotently, with lazy ``"module:Class"`` entry points):

=============================== ==============================================
id                              class
=============================== ==============================================
``pbicrl/PointMass-v0``         :class:`pbicrl.envs.point_mass.PointMassEnv`
``pbicrl/FetchReachConstrained-v0`` :class:`pbicrl.envs.fetch_reach.FetchReachConstrainedEnv`
``pbicrl/Grid3x3-v0``           :class:`pbicrl.envs.grid.GridEnv`
``pbicrl/BlockedHalfCheetah-v0`` :class:`pbicrl.envs.icrl_benchmark.BlockedHalfCheetahEnv`
``pbicrl/BlockedAnt-v0``        :class:`pbicrl.envs.icrl_benchmark.BlockedAntEnv`
``pbicrl/BiasedPendulum-v0``    :class:`pbicrl.envs.icrl_benchmark.BiasedPendulumEnv`
``pbicrl/BlockedWalker-v0``     :class:`pbicrl.envs.icrl_benchmark.BlockedWalkerEnv`
``pbicrl/BlockedSwimmer-v0``    :class:`pbicrl.envs.icrl_benchmark.BlockedSwimmerEnv`
=============================== ==============================================

Time limits are handled inside the environments (``truncated``), so no ``TimeLimit``
wrapper is added.
"""

from __future__ import annotations

__all__ = ["ENV_IDS", "register_envs"]

ENV_IDS: dict[str, str] = {
    "pbicrl/PointMass-v0": "pbicrl.envs.point_mass:PointMassEnv",
    "pbicrl/FetchReachConstrained-v0": "pbicrl.envs.fetch_reach:FetchReachConstrainedEnv",
    "pbicrl/Grid3x3-v0": "pbicrl.envs.grid:GridEnv",
    # the ICRL benchmark's virtual tasks (Liu et al., ICLR 2023); pbicrl.envs.icrl_benchmark.ICRL_TASKS
    "pbicrl/BlockedHalfCheetah-v0": "pbicrl.envs.icrl_benchmark:BlockedHalfCheetahEnv",
    "pbicrl/BlockedAnt-v0": "pbicrl.envs.icrl_benchmark:BlockedAntEnv",
    "pbicrl/BiasedPendulum-v0": "pbicrl.envs.icrl_benchmark:BiasedPendulumEnv",
    "pbicrl/BlockedWalker-v0": "pbicrl.envs.icrl_benchmark:BlockedWalkerEnv",
    "pbicrl/BlockedSwimmer-v0": "pbicrl.envs.icrl_benchmark:BlockedSwimmerEnv",
}


def register_envs() -> list[str]:
    """Register the ids above with Gymnasium (no-op for ids already registered).

    Returns
    -------
    list of str
        The registered ids.
    """
    try:
        import gymnasium as gym
    except ImportError as exc:
        raise ImportError('registering environments needs gymnasium: pip install "pbicrl[envs]"') from exc
    for env_id, entry in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry, disable_env_checker=True)
    return list(ENV_IDS)
