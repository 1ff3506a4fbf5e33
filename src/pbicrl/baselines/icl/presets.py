"""ICL's settings (:class:`ICLConfig`) and the named budgets (:func:`icl_preset`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from pbicrl.baselines.ppo_lagrangian import PPOLagConfig

__all__ = ["PRESETS", "ENVS", "ICLConfig", "icl_preset"]

PRESETS = ("smoke", "default", "paper")
ENVS = ("halfcheetah", "ant", "point_mass", "icrl_halfcheetah", "icrl_ant", "icrl_walker", "icrl_pendulum",
        "icrl_swimmer")
# The ICRL tasks use their robot's budgets; the walker, pendulum and swimmer, which have none of their own, Ant's
# (6 rounds; the benchmark driver scales the rounds to a task's budget, see icrl_config)
_PRESET_OF = {"icrl_halfcheetah": "halfcheetah", "icrl_ant": "ant", "icrl_walker": "ant", "icrl_pendulum": "ant",
              "icrl_swimmer": "ant"}


@dataclass
class ICLConfig:
    """Settings of one ICL run.

    Attributes
    ----------
    rounds : int
        Outer rounds (constrained RL, then constraint adjustment).
    first_round_steps, round_steps : int
        Environment steps of PPO-Lagrangian in round 1 and in each later round (the policy is warm-started
        from the previous round's unless ``reinit_policy``).
    beta : float
        Budget on the expected discounted cost, used by both the RL and the constraint adjustment.
    gamma : float
        Discount of :math:`J_c` (also PPO's cost discount).
    hinge_weight : float
        :math:`\\lambda_h`, weight of the expert-budget hinge in the constraint loss.
    constraint_hidden : tuple of int
        Hidden layers (ReLU) of the constraint MLP.
    constraint_lr, constraint_steps : float, int
        Adam learning rate and full-batch steps of each constraint adjustment.
    init_bias : float
        Initial output bias (pre-sigmoid) of the constraint net; -5 gives c ~ 0.007 everywhere, so round 1
        is nearly unconstrained RL (a random sigmoid net would put c ~ 0.5 everywhere, an infeasible budget).
    policy_episodes : int
        Episodes sampled from each round's policy for the constraint adjustment.
    weighting : {"dissimilarity", "uniform", "last"}
        Mixture weights of the policies (:func:`mixture_weights`).
    accrual_bins : int
        Bins per coordinate dimension of the accrual histograms.
    reinit_policy : bool
        Start every round's RL from a fresh policy instead of the previous one.
    eval_episodes : int
        Episodes of the final policy rolled out for the report.
    checkpoint_every : int
        Environment steps between checkpoints inside a round.
    ppo : PPOLagConfig
        PPO-Lagrangian settings (its ``cost_budget`` and ``cost_gamma`` are set from ``beta`` and ``gamma``).
    """

    rounds: int = 8
    first_round_steps: int = 1_000_000
    round_steps: int = 500_000
    beta: float = 1.0
    gamma: float = 0.99
    hinge_weight: float = 10.0
    constraint_hidden: tuple[int, ...] = (64, 64)
    constraint_lr: float = 3e-3
    constraint_steps: int = 300
    init_bias: float = -5.0
    policy_episodes: int = 10
    weighting: str = "dissimilarity"
    accrual_bins: int = 40
    reinit_policy: bool = False
    eval_episodes: int = 10
    checkpoint_every: int = 100_000
    ppo: PPOLagConfig = field(default_factory=PPOLagConfig)

    def validate(self) -> ICLConfig:
        """Check every option (raises ValueError naming it) and tie PPO's budget/discount to ours."""
        for name in ("rounds", "first_round_steps", "round_steps", "constraint_steps", "policy_episodes",
                     "accrual_bins", "eval_episodes", "checkpoint_every"):
            v = getattr(self, name)
            if int(v) != v or int(v) < 1:
                raise ValueError(f"icl.{name}: must be an integer >= 1, got {v!r}")
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise ValueError(f"icl.beta: must be a finite number >= 0, got {self.beta!r}")
        if not 0.0 < self.gamma <= 1.0:
            raise ValueError(f"icl.gamma: must be in (0, 1], got {self.gamma!r}")
        for name in ("hinge_weight", "constraint_lr"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"icl.{name}: must be a finite number > 0, got {v!r}")
        if not math.isfinite(self.init_bias):
            raise ValueError(f"icl.init_bias: must be finite, got {self.init_bias!r}")
        if self.weighting not in ("dissimilarity", "uniform", "last"):
            raise ValueError(f"icl.weighting: expected 'dissimilarity', 'uniform' or 'last', got {self.weighting!r}")
        hidden = tuple(int(h) for h in self.constraint_hidden)
        if not hidden or min(hidden) < 1:
            raise ValueError(f"icl.constraint_hidden: must be a non-empty list of positive sizes, got {self.constraint_hidden!r}")
        self.constraint_hidden = hidden
        if isinstance(self.ppo, dict):
            self.ppo = PPOLagConfig(**self.ppo)
        self.ppo = replace(self.ppo, cost_budget=float(self.beta), cost_gamma=float(self.gamma)).validate()
        return self

    @property
    def total_steps(self) -> int:
        """Environment steps of constrained RL over all rounds."""
        return int(self.first_round_steps + (self.rounds - 1) * self.round_steps)

    def round_target(self, r: int) -> int:
        """Cumulative PPO steps at the end of round ``r`` (0-based)."""
        return int(self.first_round_steps + r * self.round_steps)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``ICLConfig.from_dict`` inverts it)."""
        d = asdict(self)
        d["constraint_hidden"] = list(self.constraint_hidden)
        d["ppo"] = self.ppo.to_dict() if isinstance(self.ppo, PPOLagConfig) else dict(self.ppo)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ICLConfig:
        """Build from :meth:`to_dict` output; unknown keys are an error naming them."""
        known = {f for f in cls.__dataclass_fields__}
        bad = sorted(set(d) - known)
        if bad:
            raise ValueError(f"icl: unknown option(s) {bad}; known: {sorted(known)}")
        d = dict(d)
        ppo = d.pop("ppo", {})
        if isinstance(ppo, dict):
            pk = set(PPOLagConfig.__dataclass_fields__)
            badp = sorted(set(ppo) - pk)
            if badp:
                raise ValueError(f"icl.ppo: unknown option(s) {badp}; known: {sorted(pk)}")
            ppo = PPOLagConfig(**ppo)
        return cls(**d, ppo=ppo).validate()


def icl_preset(name: str, env: str = "halfcheetah") -> ICLConfig:
    """The named budget for an environment.

    ``smoke``
        A few thousand steps: exercises every part in well under a minute (tests), learns little.
    ``default``
        Sized for one seed in about 45 minutes on a shared 2-core CPU: HalfCheetah 8 rounds,
        1 M + 7 x 0.5 M = 4.5 M PPO steps (measured here: ~2,700-3,200 steps/s including the PPO updates; an
        unconstrained policy passes x = 40 after 0.2 M steps); Ant (simulation ~3.5x slower) 6 rounds,
        1 M + 5 x 0.3 M = 2.5 M steps; point mass 5 rounds x 100 k steps.
    ``paper``
        For a workstation: HalfCheetah/Ant 10 rounds, 2 M + 9 x 1 M = 11 M PPO steps, 20 policy episodes per
        round (2.4x the default's RL; not run here). Not the authors' settings, which the PBICRL paper does not
        print (it reports ~20,000 s per ICL seed).

    The ICRL benchmark's ``icrl_halfcheetah`` and ``icrl_ant`` get the budgets of ``halfcheetah`` and ``ant``,
    ``icrl_walker``, ``icrl_pendulum`` and ``icrl_swimmer`` (no budgets of their own) those of ``ant``.
    """
    if name not in PRESETS:
        raise ValueError(f"budget: unknown preset {name!r}; choose one of {PRESETS}")
    if env not in ENVS:
        raise ValueError(f"env: unknown ICL environment {env!r}; choose one of {ENVS}")
    env = _PRESET_OF.get(env, env)
    if env == "point_mass":
        ppo = PPOLagConfig(n_envs=4, n_steps=256, minibatch_size=256, n_epochs=10, init_log_std=0.0)
        if name == "smoke":
            return ICLConfig(rounds=2, first_round_steps=4096, round_steps=2048, beta=1.0, constraint_steps=100,
                             policy_episodes=4, eval_episodes=4, checkpoint_every=2048,
                             ppo=replace(ppo, n_steps=256, n_envs=4)).validate()
        steps = 100_000 if name == "default" else 300_000
        return ICLConfig(rounds=5 if name == "default" else 10, first_round_steps=steps, round_steps=steps,
                         beta=1.0, checkpoint_every=20_000, ppo=ppo).validate()
    ppo = PPOLagConfig(n_envs=4, n_steps=512, minibatch_size=256, n_epochs=10)
    if name == "smoke":
        return ICLConfig(rounds=2, first_round_steps=4096, round_steps=2048, constraint_steps=50,
                         policy_episodes=2, eval_episodes=2, checkpoint_every=2048,
                         ppo=replace(ppo, n_steps=256)).validate()
    if name == "default":
        if env == "ant":
            return ICLConfig(rounds=6, first_round_steps=1_000_000, round_steps=300_000, checkpoint_every=50_000,
                             ppo=ppo).validate()
        return ICLConfig(rounds=8, first_round_steps=1_000_000, round_steps=500_000, ppo=ppo).validate()
    return ICLConfig(rounds=10, first_round_steps=2_000_000, round_steps=1_000_000, policy_episodes=20,
                     eval_episodes=20, checkpoint_every=200_000, ppo=ppo).validate()
