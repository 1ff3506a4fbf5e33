"""A small PPO-Lagrangian (constrained PPO) for Gymnasium environments with a *learned* per-step cost.

The constrained problem is :math:`\\max_\\pi J_r(\\pi)` subject to
:math:`J_c(\\pi) = \\mathbb{E}[\\sum_t \\gamma_c^t c(s_{t+1})] \\le \\beta`. PPO optimises the Lagrangian with
the combined advantage :math:`(A_r - \\lambda A_c) / (1 + \\lambda)`; after every rollout the multiplier takes
a projected gradient step on the *expected discounted cost* of the episodes that finished in it
(or their plain cost sum, ``PPOLagConfig.episode_cost="sum"``; :func:`lagrange_update`): it rises while
:math:`\\hat J_c > \\beta` and falls (to no less than 0) otherwise.
(The ICL authors' public code drives the multiplier with the episode reward; we use the cost, as the
Lagrangian method prescribes.)

The cost is a function of a *constrained coordinate* of the state reached by each step (for the wall
environments the x-position, for the point mass the position), read by a user-given ``coord_fn(obs, info)``
and scored in one batch after each rollout by ``cost_fn`` (e.g. ICL's constraint network), so the cost can
change between calls to :meth:`PPOLagrangian.learn` without touching the environments.

Conventions (as in widely used PPO implementations): Gaussian policy with a state-independent log standard
deviation, separate reward and cost critics, GAE, clipped surrogate, running observation normalisation and
reward scaling by the running standard deviation of the discounted return, time-limit truncation
bootstrapped with the critics. Everything runs on the CPU with ``torch.set_num_threads(torch_threads)``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

try:
    import torch
    from torch import nn
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError('pbicrl.baselines needs PyTorch: pip install "pbicrl[rl]"') from exc

__all__ = [
    "ActorCritic",
    "PPOLagConfig",
    "PPOLagrangian",
    "RunningMeanStd",
    "discounted_sum",
    "gae",
    "lagrange_adam_update",
    "lagrange_update",
]


@dataclass
class PPOLagConfig:
    """Hyperparameters of :class:`PPOLagrangian` (all recorded in run metadata).

    Attributes
    ----------
    n_envs : int
        Environments stepped in lock-step (one batched policy forward pass per step).
    n_steps : int
        Steps per environment per rollout (a rollout holds ``n_envs * n_steps`` transitions).
    gamma, gae_lambda : float
        Reward discount and GAE parameter.
    cost_gamma : float
        Discount of the cost (also the discount of :math:`J_c` compared with ``cost_budget``).
    clip : float
        PPO ratio clip.
    lr : float
        Adam learning rate (policy and critics).
    n_epochs, minibatch_size : int
        PPO epochs per rollout and minibatch size.
    hidden : tuple of int
        Hidden layers of the policy and of each critic (tanh).
    init_log_std : float
        Initial log standard deviation of the Gaussian policy.
    ent_coef, vf_coef, max_grad_norm : float
        Entropy bonus, critic loss weight, gradient-norm clip (per network).
    target_kl : float or None
        Stop the epochs of an update early when the approximate KL exceeds it.
    cost_budget : float
        :math:`\\beta`, the budget on the expected discounted cost.
    lagrange_lr, lagrange_init : float
        Step size and initial value of the multiplier.
    lagrange_max : float
        Upper clip of the multiplier (keeps the combined advantage from vanishing).
    lagrange_min : float
        Lower clip of the multiplier (default 0). The ICRL benchmark's PPO-Lagrangian never lets the multiplier
        fall below its initial value :math:`\\nu_0`; set ``lagrange_min = lagrange_init`` for that.
    lagrange_optimizer : {"sgd", "adam"}
        ``"sgd"`` (default): the projected gradient step of :func:`lagrange_update`. ``"adam"``: the ICRL
        benchmark's dual variable, :math:`\\lambda = \\mathrm{softplus}(\\theta)` with one Adam step (learning rate
        ``lagrange_lr``, betas 0.9/0.999) on :math:`\\theta` per rollout for the loss
        :math:`-\\lambda(\\hat J_c - \\beta)`, then :math:`\\lambda` clipped to [``lagrange_min``, ``lagrange_max``]
        (:func:`lagrange_adam_update`).
    scale_cost : bool
        Divide the costs seen by the cost critic by the running std of the discounted cost return (clip 10), as the
        ICRL benchmark does (default False). The multiplier always sees the raw costs.
    normalize_obs, scale_reward : bool
        Running observation normalisation; reward scaling by the running std of the discounted return.
    torch_threads : int
        ``torch.set_num_threads`` (1: fastest for these small networks on a shared CPU).
    episode_cost : {"discounted", "sum", "step"}
        What the multiplier compares with ``cost_budget``: the discounted episode cost
        :math:`\\sum_t \\gamma_c^t c_t` (default, as ICL), its plain sum :math:`\\sum_t c_t` (a budget on
        the expected cost per episode; the cost critic stays discounted with ``cost_gamma``), or ``"step"``, the
        mean per-step cost of the rollout (as the ICRL benchmark's PPO-Lagrangian; every rollout updates the
        multiplier, whether or not an episode finished in it).
    """

    n_envs: int = 4
    n_steps: int = 512
    gamma: float = 0.99
    gae_lambda: float = 0.95
    cost_gamma: float = 0.99
    clip: float = 0.2
    lr: float = 3e-4
    n_epochs: int = 10
    minibatch_size: int = 256
    hidden: tuple[int, ...] = (64, 64)
    init_log_std: float = -0.5
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = 0.05
    cost_budget: float = 1.0
    lagrange_lr: float = 0.05
    lagrange_init: float = 0.0
    lagrange_max: float = 100.0
    normalize_obs: bool = True
    scale_reward: bool = True
    torch_threads: int = 1
    episode_cost: str = "discounted"
    lagrange_min: float = 0.0
    lagrange_optimizer: str = "sgd"
    scale_cost: bool = False

    def validate(self) -> PPOLagConfig:
        """Check every option; raise ValueError naming the bad one. Returns self."""
        for name in ("n_envs", "n_steps", "n_epochs", "minibatch_size", "torch_threads"):
            v = getattr(self, name)
            if int(v) != v or int(v) < 1:
                raise ValueError(f"ppo.{name}: must be an integer >= 1, got {v!r}")
        for name in ("gamma", "gae_lambda", "cost_gamma"):
            v = getattr(self, name)
            if not 0.0 < float(v) <= 1.0:
                raise ValueError(f"ppo.{name}: must be in (0, 1], got {v!r}")
        for name in ("clip", "lr", "lagrange_lr", "max_grad_norm", "lagrange_max"):
            v = getattr(self, name)
            if not (math.isfinite(float(v)) and float(v) > 0):
                raise ValueError(f"ppo.{name}: must be a finite number > 0, got {v!r}")
        for name in ("cost_budget", "lagrange_init", "ent_coef", "vf_coef", "lagrange_min"):
            v = getattr(self, name)
            if not (math.isfinite(float(v)) and float(v) >= 0):
                raise ValueError(f"ppo.{name}: must be a finite number >= 0, got {v!r}")
        if self.episode_cost not in ("discounted", "sum", "step"):
            raise ValueError(f"ppo.episode_cost: must be 'discounted', 'sum' or 'step', got {self.episode_cost!r}")
        if self.lagrange_optimizer not in ("sgd", "adam"):
            raise ValueError(f"ppo.lagrange_optimizer: must be 'sgd' or 'adam', got {self.lagrange_optimizer!r}")
        if float(self.lagrange_min) > float(self.lagrange_max):
            raise ValueError(f"ppo.lagrange_min: must be <= lagrange_max ({self.lagrange_max}), "
                             f"got {self.lagrange_min!r}")
        if self.target_kl is not None and not float(self.target_kl) > 0:
            raise ValueError(f"ppo.target_kl: must be > 0 or None, got {self.target_kl!r}")
        hidden = tuple(int(h) for h in self.hidden)
        if not hidden or min(hidden) < 1:
            raise ValueError(f"ppo.hidden: must be a non-empty list of positive sizes, got {self.hidden!r}")
        self.hidden = hidden
        return self

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        d = asdict(self)
        d["hidden"] = list(self.hidden)
        if d["episode_cost"] == "discounted":
            # absent at its default, so configs (and the hashes and checkpoints keyed on them) made before
            # the option existed stay equal
            del d["episode_cost"]
        for key, default in (("lagrange_min", 0.0), ("lagrange_optimizer", "sgd"), ("scale_cost", False)):
            if d[key] == default:
                del d[key]  # likewise
        return d


def lagrange_update(lam: float, expected_cost: float, budget: float, lr: float, lam_max: float = math.inf,
                    lam_min: float = 0.0) -> float:
    """One projected gradient-ascent step of the Lagrange multiplier on the dual.

    :math:`\\lambda \\leftarrow \\min(\\lambda_{max}, \\max(\\lambda_{min}, \\lambda + \\eta (\\hat J_c - \\beta)))`
    (:math:`\\lambda_{min} = 0` by default): the multiplier grows while the expected discounted cost exceeds the
    budget and shrinks otherwise.
    """
    if not (math.isfinite(expected_cost) and math.isfinite(budget)):
        raise ValueError(f"lagrange_update: cost {expected_cost} and budget {budget} must be finite")
    return float(min(lam_max, max(lam_min, lam + lr * (expected_cost - budget))))


def lagrange_adam_update(lam: float, expected_cost: float, budget: float, lr: float, state: dict[str, float],
                         lam_max: float = math.inf, lam_min: float = 0.0) -> float:
    """One Adam step of a softplus-parametrised multiplier (the ICRL benchmark's dual variable).

    :math:`\\lambda = \\log(1 + e^\\theta)`; the loss :math:`-\\lambda(\\hat J_c - \\beta)` has gradient
    :math:`g = -(\\hat J_c - \\beta)\\,\\sigma(\\theta)`; Adam (betas 0.9, 0.999, eps 1e-8) moves :math:`\\theta`,
    whose first and second moments and step count live in ``state`` (keys ``m``, ``v``, ``t``; updated in
    place). The result is clipped to [``lam_min``, ``lam_max``].
    """
    if not (math.isfinite(expected_cost) and math.isfinite(budget)):
        raise ValueError(f"lagrange_adam_update: cost {expected_cost} and budget {budget} must be finite")
    lam = max(float(lam), 1e-12)
    theta = lam + math.log(-math.expm1(-lam))  # inverse softplus
    g = -(expected_cost - budget) / (1.0 + math.exp(-theta))
    t = int(state.get("t", 0)) + 1
    m = 0.9 * float(state.get("m", 0.0)) + 0.1 * g
    v = 0.999 * float(state.get("v", 0.0)) + 0.001 * g * g
    state.update(m=m, v=v, t=t)
    theta -= lr * (m / (1 - 0.9**t)) / (math.sqrt(v / (1 - 0.999**t)) + 1e-8)
    new = theta + math.log1p(math.exp(-theta)) if theta > 0 else math.log1p(math.exp(theta))
    return float(min(lam_max, max(lam_min, new)))


def discounted_sum(values: NDArray[np.float64], gamma: float) -> float:
    """:math:`\\sum_t \\gamma^t v_t` of a 1-D array."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    return float(np.sum(v * gamma ** np.arange(v.size)))


def gae(rewards: NDArray, values: NDArray, dones: NDArray, last_values: NDArray, gamma: float,
        lam: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Generalised advantage estimation over a (T, E) rollout.

    ``dones[t]`` marks that the episode ended at step ``t`` (the next row starts a new one); a truncated
    episode's bootstrap value must already be folded into ``rewards[t]``.

    Returns
    -------
    (advantages, returns) : ndarrays of shape (T, E)
    """
    T = rewards.shape[0]
    adv = np.zeros_like(rewards, dtype=np.float64)
    last = np.zeros(rewards.shape[1:], dtype=np.float64)
    for t in range(T - 1, -1, -1):
        nxt = last_values if t == T - 1 else values[t + 1]
        live = 1.0 - dones[t]
        delta = rewards[t] + gamma * nxt * live - values[t]
        last = delta + gamma * lam * live * last
        adv[t] = last
    return adv, adv + values


class RunningMeanStd:
    """Running mean and variance (parallel Welford update)."""

    def __init__(self, shape: tuple[int, ...] = ()) -> None:
        self.mean = np.zeros(shape, dtype=np.float64)
        self.var = np.ones(shape, dtype=np.float64)
        self.count = 1e-4

    def update(self, x: NDArray) -> None:
        x = np.asarray(x, dtype=np.float64)
        bm, bv, bc = x.mean(axis=0), x.var(axis=0), x.shape[0]
        delta = bm - self.mean
        tot = self.count + bc
        self.mean = self.mean + delta * bc / tot
        m2 = self.var * self.count + bv * bc + delta**2 * self.count * bc / tot
        self.var = m2 / tot
        self.count = tot

    def state(self) -> dict[str, Any]:
        return {"mean": torch.as_tensor(self.mean), "var": torch.as_tensor(self.var), "count": float(self.count)}

    def load(self, st: dict[str, Any]) -> None:
        self.mean = st["mean"].numpy().astype(np.float64)
        self.var = st["var"].numpy().astype(np.float64)
        self.count = float(st["count"])


def _mlp(n_in: int, hidden: Sequence[int], n_out: int, out_gain: float) -> nn.Sequential:
    layers: list[nn.Module] = []
    last = n_in
    for h in hidden:
        lin = nn.Linear(last, h)
        nn.init.orthogonal_(lin.weight, math.sqrt(2))
        nn.init.zeros_(lin.bias)
        layers += [lin, nn.Tanh()]
        last = h
    out = nn.Linear(last, n_out)
    nn.init.orthogonal_(out.weight, out_gain)
    nn.init.zeros_(out.bias)
    layers.append(out)
    return nn.Sequential(*layers)


class ActorCritic(nn.Module):
    """Gaussian policy (state-independent log std), reward critic and cost critic."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int], init_log_std: float) -> None:
        super().__init__()
        self.pi = _mlp(obs_dim, hidden, act_dim, 0.01)
        self.v = _mlp(obs_dim, hidden, 1, 1.0)
        self.vc = _mlp(obs_dim, hidden, 1, 1.0)
        self.log_std = nn.Parameter(torch.full((act_dim,), float(init_log_std)))

    def dist(self, obs: torch.Tensor) -> torch.distributions.Normal:
        return torch.distributions.Normal(self.pi(obs), self.log_std.exp())

    def values(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.v(obs).squeeze(-1), self.vc(obs).squeeze(-1)


@dataclass
class _EpisodeStats:
    returns: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    costs: list[float] = field(default_factory=list)  # episode cost (discounted unless episode_cost="sum")
    max_coord: list[float] = field(default_factory=list)


class PPOLagrangian:
    """PPO-Lagrangian on ``n_envs`` environments with a learned cost of a state coordinate.

    Parameters
    ----------
    env_fn : callable
        Zero-argument factory of a Gymnasium environment (time limit included); called ``n_envs`` times.
    coord_fn : callable
        ``coord_fn(next_obs, info) -> array (k,)``: the constrained coordinate of the state a step reached.
    cost_fn : callable
        ``cost_fn(coords (N, k)) -> costs (N,)`` in [0, 1]; replace it with :meth:`set_cost_fn`.
    config : PPOLagConfig
    seed : int
        Seeds torch, the action noise and the environment resets.
    fused_optimizer : bool
        Use torch's fused Adam (the same algorithm, one kernel per step: about 5 times faster per step for these
        small networks on a CPU, with rounding-level differences). Falls back to the default Adam where torch
        lacks it. Not part of the config: it does not change what is optimised.
    """

    def __init__(self, env_fn: Callable[[], Any], coord_fn: Callable[[Any, dict], NDArray],
                 cost_fn: Callable[[NDArray], NDArray], config: PPOLagConfig | None = None, *, seed: int = 0,
                 fused_optimizer: bool = False) -> None:
        self.cfg = (config or PPOLagConfig()).validate()
        torch.set_num_threads(int(self.cfg.torch_threads))
        torch.manual_seed(int(seed))
        self.seed = int(seed)
        self.envs = [env_fn() for _ in range(self.cfg.n_envs)]
        space = self.envs[0].observation_space
        aspace = self.envs[0].action_space
        self.obs_dim = int(np.prod(space.shape))
        self.act_dim = int(np.prod(aspace.shape))
        self.act_low = np.asarray(aspace.low, dtype=np.float64)
        self.act_high = np.asarray(aspace.high, dtype=np.float64)
        self.coord_fn = coord_fn
        self.cost_fn = cost_fn
        self.ac = ActorCritic(self.obs_dim, self.act_dim, self.cfg.hidden, self.cfg.init_log_std)
        self.opt = torch.optim.Adam(self.ac.parameters(), lr=self.cfg.lr, eps=1e-5)
        self.fused_optimizer = False
        if fused_optimizer:
            try:
                self.opt = torch.optim.Adam(self.ac.parameters(), lr=self.cfg.lr, eps=1e-5, fused=True)
                self.fused_optimizer = True
            except (RuntimeError, TypeError, ValueError):  # an older torch without fused Adam on the CPU
                pass
        self.obs_rms = RunningMeanStd((self.obs_dim,))
        self.ret_rms = RunningMeanStd(())
        self.cost_rms = RunningMeanStd(())  # scale_cost only
        self.lam_adam: dict[str, float] = {"m": 0.0, "v": 0.0, "t": 0}  # lagrange_optimizer="adam" only
        self.lam = float(self.cfg.lagrange_init)
        self.num_steps = 0
        self.num_updates = 0
        self._resets = 0
        self._obs: NDArray | None = None
        self.stats = _EpisodeStats()
        self.history: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ helpers
    def set_cost_fn(self, cost_fn: Callable[[NDArray], NDArray]) -> None:
        """Use a new cost function from the next rollout on."""
        self.cost_fn = cost_fn

    def _norm(self, obs: NDArray) -> NDArray:
        if not self.cfg.normalize_obs:
            return obs
        return np.clip((obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + 1e-8), -10.0, 10.0)

    def _reset_all(self) -> None:
        obs = []
        for i, env in enumerate(self.envs):
            o, _ = env.reset(seed=self.seed * 100_003 + 7919 * self._resets + i)
            obs.append(np.asarray(o, dtype=np.float64).reshape(-1))
        self._resets += 1
        self._obs = np.stack(obs)
        self._ep_ret = np.zeros(len(self.envs))
        self._ep_len = np.zeros(len(self.envs), dtype=np.int64)
        self._ret_acc = np.zeros(len(self.envs))
        self._cost_acc = np.zeros(len(self.envs))
        self._ep_costs: list[list[float]] = [[] for _ in self.envs]
        self._ep_max = np.full(len(self.envs), -np.inf)

    def act(self, obs: NDArray, deterministic: bool = False,
            generator: torch.Generator | None = None) -> NDArray[np.float64]:
        """Action (clipped to the action space) for raw observations of shape (n, obs_dim); a stochastic action
        draws its noise from ``generator`` when given (torch's global generator otherwise)."""
        x = torch.as_tensor(self._norm(np.atleast_2d(np.asarray(obs, dtype=np.float64))), dtype=torch.float32)
        with torch.no_grad():
            d = self.ac.dist(x)
            if deterministic:
                a = d.mean
            elif generator is None:
                a = d.sample()
            else:
                a = d.mean + d.stddev * torch.randn(d.mean.shape, generator=generator)
        return np.clip(a.numpy().astype(np.float64), self.act_low, self.act_high)

    # ------------------------------------------------------------------ rollout
    def _rollout(self) -> dict[str, NDArray]:
        cfg = self.cfg
        T, E = cfg.n_steps, cfg.n_envs
        if self._obs is None:
            self._reset_all()
        obs_buf = np.zeros((T, E, self.obs_dim), dtype=np.float32)
        act_buf = np.zeros((T, E, self.act_dim), dtype=np.float32)
        logp_buf = np.zeros((T, E), dtype=np.float32)
        rew_buf = np.zeros((T, E))
        val_buf = np.zeros((T, E))
        cval_buf = np.zeros((T, E))
        done_buf = np.zeros((T, E))
        boot_r = np.zeros((T, E))  # gamma * V(final obs) of time-limit truncations (scaled-reward units)
        boot_c = np.zeros((T, E))  # gamma_c * V_c(final obs), added once the costs are known
        coords: list[list[NDArray]] = []
        raw_obs = []
        gen_noise = torch.Generator().manual_seed(self.seed * 1_000_003 + self.num_updates)
        for t in range(T):
            raw_obs.append(self._obs.copy())
            x = torch.as_tensor(self._norm(self._obs), dtype=torch.float32)
            with torch.no_grad():
                d = self.ac.dist(x)
                a = d.mean + d.stddev * torch.randn(d.mean.shape, generator=gen_noise)
                logp = d.log_prob(a).sum(-1)
                v, vc = self.ac.values(x)
            obs_buf[t] = x.numpy()
            act_buf[t] = a.numpy()
            logp_buf[t] = logp.numpy()
            val_buf[t] = v.numpy()
            cval_buf[t] = vc.numpy()
            a_np = np.clip(a.numpy().astype(np.float64), self.act_low, self.act_high)
            row = []
            trunc_obs: dict[int, NDArray] = {}
            for i, env in enumerate(self.envs):
                o, r, term, trunc, info = env.step(a_np[i])
                o = np.asarray(o, dtype=np.float64).reshape(-1)
                c = np.asarray(self.coord_fn(o, info), dtype=np.float64).reshape(-1)
                row.append(c)
                self._ep_ret[i] += r
                self._ep_len[i] += 1
                self._ep_max[i] = max(self._ep_max[i], float(c[0]))
                rew_buf[t, i] = r
                if term or trunc:
                    done_buf[t, i] = 1.0
                    if trunc and not term:
                        trunc_obs[i] = o
                    self.stats.returns.append(float(self._ep_ret[i]))
                    self.stats.lengths.append(int(self._ep_len[i]))
                    self.stats.max_coord.append(float(self._ep_max[i]))
                    self._ep_ret[i], self._ep_len[i], self._ep_max[i] = 0.0, 0, -np.inf
                    o, _ = env.reset(seed=self.seed * 100_003 + 7919 * self._resets + i)
                    self._resets += 1
                    o = np.asarray(o, dtype=np.float64).reshape(-1)
                self._obs[i] = o
            coords.append(row)
            if trunc_obs:
                idx = list(trunc_obs)
                xo = torch.as_tensor(self._norm(np.stack([trunc_obs[i] for i in idx])), dtype=torch.float32)
                with torch.no_grad():
                    vb, vcb = self.ac.values(xo)
                for j, i in enumerate(idx):
                    boot_r[t, i] = cfg.gamma * float(vb[j])
                    boot_c[t, i] = cfg.cost_gamma * float(vcb[j])
        self.num_steps += T * E
        raw = np.concatenate(raw_obs)
        if cfg.normalize_obs:
            self.obs_rms.update(raw)
        with torch.no_grad():
            lv, lvc = self.ac.values(torch.as_tensor(self._norm(self._obs), dtype=torch.float32))
        C = np.asarray([[c for c in row] for row in coords])  # (T, E, k)
        cost = np.asarray(self.cost_fn(C.reshape(T * E, -1)), dtype=np.float64).reshape(T, E)
        if not np.all(np.isfinite(cost)):
            raise FloatingPointError("cost_fn returned non-finite costs")
        # episode cost bookkeeping (discounted, learned cost) for the multiplier
        finished_costs = []
        ep_gamma = cfg.cost_gamma if cfg.episode_cost == "discounted" else 1.0
        for t in range(T):
            for i in range(E):
                self._ep_costs[i].append(cost[t, i])
                if done_buf[t, i]:
                    finished_costs.append(discounted_sum(np.asarray(self._ep_costs[i]), ep_gamma))
                    self._ep_costs[i] = []
        self.stats.costs.extend(finished_costs)
        # reward scaling by the running std of the discounted return
        if cfg.scale_reward:
            for t in range(T):
                self._ret_acc = self._ret_acc * cfg.gamma + rew_buf[t]
                self.ret_rms.update(self._ret_acc)
                self._ret_acc[done_buf[t] > 0] = 0.0
            rew_scaled = rew_buf / self._reward_scale()
        else:
            rew_scaled = rew_buf
        adv_r, ret_r = gae(rew_scaled + boot_r, val_buf, done_buf, lv.numpy().astype(np.float64), cfg.gamma, cfg.gae_lambda)
        if cfg.scale_cost:
            for t in range(T):
                self._cost_acc = self._cost_acc * cfg.cost_gamma + cost[t]
                self.cost_rms.update(self._cost_acc)
                self._cost_acc[done_buf[t] > 0] = 0.0
            cost_seen = np.clip(cost / float(np.sqrt(self.cost_rms.var + 1e-8)), -10.0, 10.0)
        else:
            cost_seen = cost
        adv_c, ret_c = gae(cost_seen + boot_c, cval_buf, done_buf, lvc.numpy().astype(np.float64), cfg.cost_gamma,
                           cfg.gae_lambda)
        return {"obs": obs_buf.reshape(T * E, -1), "act": act_buf.reshape(T * E, -1), "logp": logp_buf.reshape(-1),
                "adv_r": adv_r.reshape(-1), "ret_r": ret_r.reshape(-1), "adv_c": adv_c.reshape(-1),
                "ret_c": ret_c.reshape(-1), "finished_costs": np.asarray(finished_costs),
                "mean_cost": float(cost.mean())}

    def _reward_scale(self) -> float:
        return float(np.sqrt(self.ret_rms.var + 1e-8)) if self.cfg.scale_reward else 1.0

    # ------------------------------------------------------------------ update
    def _update(self, batch: dict[str, NDArray]) -> dict[str, float]:
        cfg = self.cfg
        adv_r = batch["adv_r"]
        adv_r = (adv_r - adv_r.mean()) / (adv_r.std() + 1e-8)
        adv_c = batch["adv_c"] - batch["adv_c"].mean()
        adv = (adv_r - self.lam * adv_c) / (1.0 + self.lam)
        t = {k: torch.as_tensor(v, dtype=torch.float32) for k, v in
             (("obs", batch["obs"]), ("act", batch["act"]), ("logp", batch["logp"]), ("adv", adv),
              ("ret_r", batch["ret_r"]), ("ret_c", batch["ret_c"]))}
        n = t["obs"].shape[0]
        g = torch.Generator().manual_seed(self.seed * 7_777 + self.num_updates)
        groups = [list(self.ac.pi.parameters()) + [self.ac.log_std], list(self.ac.v.parameters()),
                  list(self.ac.vc.parameters())]
        kl = 0.0
        epochs_done = 0
        for _ in range(cfg.n_epochs):
            perm = torch.randperm(n, generator=g)
            kls = []
            for s in range(0, n, cfg.minibatch_size):
                idx = perm[s:s + cfg.minibatch_size]
                o = t["obs"][idx]
                d = self.ac.dist(o)
                logp = d.log_prob(t["act"][idx]).sum(-1)
                ratio = torch.exp(logp - t["logp"][idx])
                a = t["adv"][idx]
                pg = -torch.min(ratio * a, torch.clamp(ratio, 1 - cfg.clip, 1 + cfg.clip) * a).mean()
                v, vc = self.ac.values(o)
                vloss = 0.5 * ((v - t["ret_r"][idx]) ** 2).mean() + 0.5 * ((vc - t["ret_c"][idx]) ** 2).mean()
                ent = d.entropy().sum(-1).mean()
                loss = pg + cfg.vf_coef * vloss - cfg.ent_coef * ent
                self.opt.zero_grad()
                loss.backward()
                for grp in groups:  # clip per network: the cost critic's large errors must not starve the policy
                    nn.utils.clip_grad_norm_(grp, cfg.max_grad_norm)
                self.opt.step()
                with torch.no_grad():
                    kls.append(float(((ratio - 1) - torch.log(ratio)).mean()))
            epochs_done += 1
            kl = float(np.mean(kls))
            if cfg.target_kl is not None and kl > cfg.target_kl:
                break
        self.num_updates += 1
        return {"approx_kl": kl, "epochs": epochs_done, "policy_loss": float(pg.detach()), "value_loss": float(vloss.detach()),
                "std": float(self.ac.log_std.detach().exp().mean())}

    # ------------------------------------------------------------------ public
    def learn(self, until_steps: int, *, callback: Callable[[PPOLagrangian, dict], bool] | None = None) -> int:
        """Train until ``num_steps >= until_steps`` (a total, so resumed runs call it with the same target).

        ``callback(self, info)`` runs after every update; returning False stops early. Returns ``num_steps``.
        """
        while self.num_steps < int(until_steps):
            t0 = time.perf_counter()
            batch = self._rollout()
            fc = batch["finished_costs"]
            lam_before = self.lam
            jc = batch["mean_cost"] if self.cfg.episode_cost == "step" else (float(fc.mean()) if fc.size else None)
            if jc is not None and self.cfg.lagrange_optimizer == "adam":
                self.lam = lagrange_adam_update(self.lam, jc, self.cfg.cost_budget, self.cfg.lagrange_lr,
                                                self.lam_adam, self.cfg.lagrange_max, self.cfg.lagrange_min)
            elif jc is not None:
                self.lam = lagrange_update(self.lam, jc, self.cfg.cost_budget, self.cfg.lagrange_lr,
                                           self.cfg.lagrange_max, self.cfg.lagrange_min)
            info = self._update(batch)
            recent = slice(-max(1, len(fc)) if fc.size else -10, None)
            info.update(steps=self.num_steps, lam=lam_before, lam_next=self.lam,
                        ep_cost=float(fc.mean()) if fc.size else float("nan"),
                        ep_return=float(np.mean(self.stats.returns[recent])) if self.stats.returns else float("nan"),
                        ep_len=float(np.mean(self.stats.lengths[recent])) if self.stats.lengths else float("nan"),
                        ep_max_coord=float(np.mean(self.stats.max_coord[recent])) if self.stats.max_coord else float("nan"),
                        seconds=time.perf_counter() - t0)
            self.history.append(info)
            if callback is not None and callback(self, info) is False:
                break
        return self.num_steps

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume (networks, optimiser, normalisers, multiplier, counters)."""
        return {"ac": self.ac.state_dict(), "opt": self.opt.state_dict(), "obs_rms": self.obs_rms.state(),
                "ret_rms": self.ret_rms.state(), "lam": self.lam, "num_steps": self.num_steps,
                "num_updates": self.num_updates, "resets": self._resets, "config": self.cfg.to_dict(),
                **({"cost_rms": self.cost_rms.state()} if self.cfg.scale_cost else {}),
                **({"lam_adam": dict(self.lam_adam)} if self.cfg.lagrange_optimizer == "adam" else {})}

    def load_state_dict(self, st: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` output (environments restart from a reset)."""
        self.ac.load_state_dict(st["ac"])
        self.opt.load_state_dict(st["opt"])
        for group in self.opt.param_groups:  # the saved groups carry the writer's flags
            group["fused"] = True if self.fused_optimizer else group.get("fused")
            if self.fused_optimizer:
                group["foreach"] = None
        self.obs_rms.load(st["obs_rms"])
        self.ret_rms.load(st["ret_rms"])
        self.lam = float(st["lam"])
        self.num_steps = int(st["num_steps"])
        self.num_updates = int(st["num_updates"])
        self._resets = int(st["resets"]) + 1
        if "cost_rms" in st:
            self.cost_rms.load(st["cost_rms"])
        if "lam_adam" in st:
            self.lam_adam = {"m": float(st["lam_adam"]["m"]), "v": float(st["lam_adam"]["v"]),
                             "t": int(st["lam_adam"]["t"])}
        self._obs = None

    def close(self) -> None:
        for env in self.envs:
            env.close()
