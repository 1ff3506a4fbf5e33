r"""``pbicrl train-safe``: train a policy that respects an inferred constraint (constrained RL).

The constrained problem is :math:`\max_\pi J_{r_n}(\pi)` subject to
:math:`\mathbb E_\pi[\sum_t c(s_{t+1})] \le D`: the nominal reward :math:`r_n = w_n^\top \phi` of the
environment, and a per-step cost :math:`c` from

* ``cost="inferred"`` (default): a run directory's posterior, through
  :class:`pbicrl.envs.inferred_cost.InferredConstraintCost` (``mode`` conservative - the default with parametric
  constraints -, indicator, probability, sample or penalty);
* ``cost="true"``: the environment's true constraint (1 per step inside the orange or red region, or at
  :math:`x \ge` the wall) - the reference a perfect inference would give;
* ``cost="none"``: no cost (the nominal-only policy; the multiplier stays 0).

Solver: the project's PPO-Lagrangian (:class:`pbicrl.baselines.ppo_lagrangian.PPOLagrangian`, also used by
the ICL baseline) with the budget on the plain episode cost (``episode_cost="sum"``). A maintained
implementation was looked for first (2025): OmniSafe 0.5.0 needs Safety-Gymnasium, whose every release pins
``gymnasium==0.28.1`` or ``0.26.3`` and ``mujoco==2.3.3`` (pip cannot resolve it beside Gymnasium 1.x, and
forced beside Gymnasium 1.4 it fails on import: ``gymnasium.wrappers.compatibility`` is gone); sb3-contrib
2.9 installs but has no Lagrangian or other constrained algorithm (ARS, CrossQ, MaskablePPO, QR-DQN,
RecurrentPPO, TQC, TRPO).

Run directory (``--out``): ``checkpoint.pt`` (resume point: networks, optimiser, normalisers, multiplier,
counters; read with ``torch.load(weights_only=True)``), ``progress.log``, ``budget.json`` (requested and
done steps, wall time per session, settings, versions), and at the end ``policy.pt`` and ``summary.json``
(training history, the cost's description, an evaluation of the final policy and ``cost_limit_met``: whether
its mean evaluation cost is within the limit, with a warning when it is not). Running the same command
again resumes (a larger ``--steps`` continues training); SIGINT/SIGTERM write a checkpoint and stop. The
training runs in this process and starts no child processes.

Needs torch and gymnasium (``pip install "pbicrl[rl,envs]"``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbicrl.baselines.session import SessionClock, StopSignals, library_versions, load_safely, progress_logger
from pbicrl._moved import moved_to_cli

__all__ = [
    "COSTS",
    "DEFAULT_COST_LIMIT",
    "ENVS",
    "EvalResult",
    "SafePolicy",
    "evaluate_policy",
    "load_policy",
    "make_env",
    "ppo_config",
    "train_safe",
]

ENVS: tuple[str, ...] = ("point_mass", "fetch_reach", "halfcheetah", "ant")
COSTS: tuple[str, ...] = ("inferred", "true", "none")
DEFAULT_COST_LIMIT = 1.0
"""Default :math:`D`: at most one costly step per episode on average."""
_CKPT, _POLICY = "checkpoint.pt", "policy.pt"
_KIND = "pbicrl-train-safe"
_EXTRA = 'train-safe needs torch and gymnasium: pip install "pbicrl[rl,envs]"'


def _need_rl() -> None:
    try:
        import gymnasium  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:
        raise ImportError(_EXTRA) from exc


# --------------------------------------------------------------------------------------------- environments
def make_env(name: str) -> Any:
    """The environment ``name`` (:data:`ENVS`) with its *nominal* reward (the constraint is the cost's job).

    Point mass / Fetch-Reach: ``reward_weights="nominal"``; HalfCheetah / Ant: the wall environment without
    the penalty, 500 steps per episode (:func:`pbicrl.envs.mujoco_wall.make_wall_env`).
    """
    if name == "point_mass":
        from pbicrl.envs.point_mass import PointMassEnv

        return PointMassEnv(reward_weights="nominal")
    if name == "fetch_reach":
        from pbicrl.envs.fetch_reach import FetchReachConstrainedEnv

        return FetchReachConstrainedEnv(reward_weights="nominal")
    if name in ("halfcheetah", "ant"):
        from pbicrl.envs.mujoco_wall import make_wall_env

        return make_wall_env(name, constrained=False, max_episode_steps=500)
    raise ValueError(f"env: expected one of {', '.join(ENVS)}, got {name!r}")


def _true_weights(name: str) -> NDArray[np.float64]:
    if name == "point_mass":
        from pbicrl.envs.point_mass import POINT_MASS_TASK as task
    else:
        from pbicrl.envs.fetch_reach import FETCH_REACH_TASK as task
    return np.asarray(task.true_weights, dtype=np.float64)


def _step_truth(name: str, reward: float, info: dict, w_true: NDArray | None) -> tuple[bool, float, float]:
    """(violation, true reward, nominal reward) of one step; see :func:`evaluate_policy`."""
    if name in ("halfcheetah", "ant"):
        nominal = float(info["nominal_reward"])
        return bool(info["in_wall"]), nominal + float(info["wall_penalty"]), nominal
    phi = np.asarray(info["features"], dtype=np.float64)
    return bool(phi[1] > 0 or phi[2] > 0), float(w_true @ phi), float(reward)  # type: ignore[operator]


def _wrap_cost(env: Any, name: str, cost: str, run: Any, mode: str, quantile: float,
               constraints: Sequence[str] | None) -> Any:
    import gymnasium as gym

    from pbicrl.envs.inferred_cost import InferredConstraintCost

    if cost == "inferred":
        return InferredConstraintCost(env, run, mode=mode, quantile=quantile, constraints=constraints)

    class _KnownCost(gym.Wrapper):
        def step(self, action: Any):
            obs, r, term, trunc, info = self.env.step(action)
            info = dict(info)
            info["cost"] = float(_step_truth(name, r, info, w)[0]) if cost == "true" else 0.0
            return obs, r, term, trunc, info

    w = None if name in ("halfcheetah", "ant") else _true_weights(name)
    return _KnownCost(env)


class _CostEnvFactory:
    """Zero-argument factory of the cost-wrapped environment (one posterior shared by all copies)."""

    def __init__(self, name: str, cost: str, run: Any, mode: str, quantile: float,
                 constraints: Sequence[str] | None) -> None:
        self.args = (name, cost, run, mode, quantile, constraints)

    def __call__(self) -> Any:
        name, cost, run, mode, quantile, constraints = self.args
        return _wrap_cost(make_env(name), name, cost, run, mode, quantile, constraints)


def ppo_config(env: str, cost_limit: float = DEFAULT_COST_LIMIT, **overrides: Any) -> Any:
    """PPO-Lagrangian settings of ``env`` with the budget ``cost_limit`` on the expected episode cost.

    Point mass / Fetch-Reach: 4 environments x 256 steps per rollout, initial log std 0 (as the ICL
    baseline's point-mass preset); HalfCheetah / Ant: 4 x 512 steps. Multiplier step 0.05 per unit of
    excess cost, capped at 100. ``overrides`` replace fields of
    :class:`pbicrl.baselines.ppo_lagrangian.PPOLagConfig`.
    """
    from pbicrl.baselines.ppo_lagrangian import PPOLagConfig

    if env not in ENVS:
        raise ValueError(f"env: expected one of {', '.join(ENVS)}, got {env!r}")
    base = (PPOLagConfig(n_envs=4, n_steps=256, minibatch_size=256, init_log_std=0.0)
            if env in ("point_mass", "fetch_reach") else PPOLagConfig(n_envs=4, n_steps=512, minibatch_size=256))
    known = set(PPOLagConfig.__dataclass_fields__)
    bad = sorted(set(overrides) - known)
    if bad:
        raise ValueError(f"ppo: unknown option(s) {bad}; known: {sorted(known)}")
    return replace(base, cost_budget=float(cost_limit), episode_cost="sum", **overrides).validate()


# --------------------------------------------------------------------------------------------- policies
@dataclass(frozen=True, eq=False)
class SafePolicy:
    """A trained policy: ``policy(obs) -> action`` (the Gaussian's mean, clipped to the action space).

    Attributes
    ----------
    net : torch.nn.Module
        :class:`pbicrl.baselines.ppo_lagrangian.ActorCritic`.
    obs_mean, obs_var : ndarray
        Running observation normalisation (``normalize``) at the end of training.
    act_low, act_high : ndarray
    normalize : bool
    env : str
    meta : dict
        What ``policy.pt`` recorded (cost, mode, steps, seed, ...).
    """

    net: Any
    obs_mean: NDArray[np.float64]
    obs_var: NDArray[np.float64]
    act_low: NDArray[np.float64]
    act_high: NDArray[np.float64]
    normalize: bool
    env: str
    meta: dict = field(default_factory=dict)

    def __call__(self, obs: Any) -> NDArray[np.float64]:
        import torch

        x = np.asarray(obs, dtype=np.float64).reshape(1, -1)
        if self.normalize:
            x = np.clip((x - self.obs_mean) / np.sqrt(self.obs_var + 1e-8), -10.0, 10.0)
        with torch.no_grad():
            a = self.net.pi(torch.as_tensor(x, dtype=torch.float32)).numpy()[0].astype(np.float64)
        return np.clip(a, self.act_low, self.act_high)


def _torch_load(path: Path, what: str) -> dict[str, Any]:
    obj = load_safely(path, what, "it is not a file of pbicrl train-safe, or it is damaged")
    if not isinstance(obj, dict) or obj.get("kind") != _KIND:
        raise ValueError(f"{what}: {path} is not a pbicrl train-safe file")
    return obj


def load_policy(out_dir: str | os.PathLike[str]) -> SafePolicy:
    """The final policy of a finished ``train-safe`` run directory (``policy.pt``)."""
    _need_rl()
    from pbicrl.baselines.ppo_lagrangian import ActorCritic

    path = Path(out_dir) / _POLICY
    if not path.is_file():
        raise FileNotFoundError(f"policy: {path}: missing (train-safe writes it when training finishes)")
    st = _torch_load(path, "policy")
    net = ActorCritic(int(st["obs_dim"]), int(st["act_dim"]), tuple(st["hidden"]), 0.0)
    net.load_state_dict(st["ac"])
    net.eval()
    return SafePolicy(net, st["obs_mean"].numpy().astype(np.float64), st["obs_var"].numpy().astype(np.float64),
                      np.asarray(st["act_low"], dtype=np.float64), np.asarray(st["act_high"], dtype=np.float64),
                      bool(st["normalize"]), str(st["env"]), dict(st.get("meta", {})))


@dataclass(frozen=True)
class EvalResult:
    r"""Per-episode outcomes of :func:`evaluate_policy`, arrays of shape (episodes,).

    Attributes
    ----------
    steps : ndarray of int
    violation_steps : ndarray of int
        Steps whose reached state is in a true constraint region (orange or red) or at/after the wall.
    true_return : ndarray
        Point mass / Fetch-Reach: :math:`\sum_t w_{true}^\top \phi(s_t)`; walls: nominal reward plus the wall
        penalty (-50 HalfCheetah, -100 Ant per step at :math:`x \ge` the wall; Ant's survival bonus excluded).
    nominal_return : ndarray
        :math:`\sum_t w_n^\top \phi(s_t)`.
    cost : ndarray or None
        Episode sum of ``info["cost"]`` when evaluated with a cost wrapper.
    max_x : ndarray or None
        HalfCheetah / Ant: the furthest x-position reached in the episode (how far short of, or past, the wall).
    """

    steps: NDArray[np.int64]
    violation_steps: NDArray[np.int64]
    true_return: NDArray[np.float64]
    nominal_return: NDArray[np.float64]
    cost: NDArray[np.float64] | None = None
    max_x: NDArray[np.float64] | None = None

    @property
    def violation_rate(self) -> float:
        """Fraction of all evaluated steps that violate the true constraint."""
        return float(self.violation_steps.sum() / max(1, self.steps.sum()))

    @property
    def violating_episodes(self) -> float:
        """Fraction of episodes with at least one violating step."""
        return float(np.mean(self.violation_steps > 0))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (means) and the per-episode arrays."""
        out = {"episodes": int(self.steps.size), "violation_rate": self.violation_rate,
               "violating_episodes": self.violating_episodes, "mean_steps": float(self.steps.mean()),
               "true_return": float(self.true_return.mean()), "nominal_return": float(self.nominal_return.mean()),
               "per_episode": {"steps": self.steps.tolist(), "violation_steps": self.violation_steps.tolist(),
                               "true_return": self.true_return.tolist(), "nominal_return": self.nominal_return.tolist()}}
        if self.cost is not None:
            out["cost"] = float(self.cost.mean())
            out["per_episode"]["cost"] = self.cost.tolist()
        if self.max_x is not None:
            out["max_x"] = float(self.max_x.mean())
            out["per_episode"]["max_x"] = self.max_x.tolist()
        return out


def evaluate_policy(policy: Callable[[Any], Any], env: str, episodes: int = 100, *, seed: int = 0,
                    cost_env: Any = None) -> EvalResult:
    """Run ``episodes`` episodes of ``policy`` on ``env`` (reset seeds ``seed, seed + 1, ...``).

    Parameters
    ----------
    policy : callable
        ``policy(obs) -> action`` (e.g. a :class:`SafePolicy`; deterministic there).
    env : str
        One of :data:`ENVS`.
    episodes : int
    seed : int
    cost_env : gymnasium.Env, optional
        An environment of kind ``env`` wrapped with a cost (``info["cost"]``) to run instead of a fresh one;
        its episode costs are returned too.
    """
    if int(episodes) < 1:
        raise ValueError(f"episodes: must be >= 1, got {episodes}")
    e = cost_env if cost_env is not None else make_env(env)
    w = None if env in ("halfcheetah", "ant") else _true_weights(env)
    wall = env in ("halfcheetah", "ant")
    steps, viol, tr, nr, cs, mx = [], [], [], [], [], []
    try:
        for k in range(int(episodes)):
            obs, _ = e.reset(seed=int(seed) + k)
            n = v = 0
            rt = rn = c = 0.0
            far = -math.inf
            while True:
                obs, r, term, trunc, info = e.step(policy(obs))
                bad, t_r, n_r = _step_truth(env, r, info, w)
                n += 1
                v += int(bad)
                rt += t_r
                rn += n_r
                c += float(info.get("cost", 0.0))
                if wall:
                    far = max(far, float(info["x_position"]))
                if term or trunc:
                    break
            steps.append(n)
            viol.append(v)
            tr.append(rt)
            nr.append(rn)
            cs.append(c)
            mx.append(far)
    finally:
        if cost_env is None:
            e.close()
    return EvalResult(np.asarray(steps, dtype=np.int64), np.asarray(viol, dtype=np.int64), np.asarray(tr),
                      np.asarray(nr), np.asarray(cs) if cost_env is not None else None,
                      np.asarray(mx) if wall else None)


# --------------------------------------------------------------------------------------------- training
def _file_sha256(paths: Sequence[Path]) -> str:
    h = hashlib.sha256()
    for p in paths:
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def train_safe(out_dir: str | os.PathLike[str], env: str, steps: int, cost_limit: float = DEFAULT_COST_LIMIT, *,
               run: str | os.PathLike[str] | None = None, cost: str = "inferred", mode: str | None = None,
               quantile: float = 0.5, constraints: Sequence[str] | None = None, seed: int = 0,
               ppo: dict[str, Any] | None = None, warmup_steps: int = 0, eval_episodes: int = 20,
               checkpoint_every: int | None = None,
               max_session_steps: int | None = None, progress: bool = True,
               log_every_s: float = 15.0) -> dict[str, Any]:
    r"""Train (or resume) a constrained policy and return its summary (also ``out_dir/summary.json``).

    Parameters
    ----------
    out_dir : path
        Run directory (see the module docstring). An existing one is resumed when it holds a checkpoint of
        the same settings; any other non-empty directory is refused.
    env : str
        One of :data:`ENVS`.
    steps : int
        Total environment steps (a resumed run trains up to this total).
    cost_limit : float
        :math:`D \ge 0`, budget on the expected cost per episode.
    run : path, optional
        Run directory of ``pbicrl infer`` (required for ``cost="inferred"``).
    cost : {"inferred", "true", "none"}
    mode, quantile, constraints
        Of :class:`pbicrl.envs.inferred_cost.InferredConstraintCost` (``cost="inferred"`` only; the default mode
        is ``conservative`` for a posterior with parametric constraints, else ``indicator``).
    seed : int
        Seeds torch, the action noise and the environment resets.
    ppo : dict, optional
        Overrides of :func:`ppo_config`.
    warmup_steps : int
        The first ``warmup_steps`` steps see a zero cost (nominal training; the multiplier stays 0). Where a
        random policy already pays cost (the point mass's random walk from the edges enters the discs), the
        multiplier otherwise rises before the task is learned, and with a small budget :math:`D` it falls
        only by ``lagrange_lr * D`` per update: the policy learns to stand still first.
    eval_episodes : int
        Episodes of the final deterministic policy evaluated into the summary (0: none).
    checkpoint_every : int, optional
        Steps between checkpoints (default: a tenth of ``steps``, at least one rollout).
    max_session_steps : int, optional
        Stop (checkpoint, then ``KeyboardInterrupt``) after this many steps in this call.
    progress : bool
        Echo the progress lines to stderr (they always go to ``progress.log``).
    log_every_s : float
        Seconds between progress lines.

    Raises
    ------
    ValueError, FileNotFoundError
        Bad settings, run directory or output directory (the message names the argument); checked before
        anything is written.
    KeyboardInterrupt
        On SIGINT/SIGTERM or after ``max_session_steps``, once the checkpoint is written.
    """
    _need_rl()
    import torch

    from pbicrl.baselines.icl import save_checkpoint, write_json_file
    from pbicrl.baselines.ppo_lagrangian import PPOLagrangian

    # ---- every check before anything is written
    if env not in ENVS:
        raise ValueError(f"env: expected one of {', '.join(ENVS)}, got {env!r}")
    if cost not in COSTS:
        raise ValueError(f"cost: expected one of {', '.join(COSTS)}, got {cost!r}")
    if isinstance(steps, bool) or int(steps) != steps or int(steps) < 1:
        raise ValueError(f"steps: must be an integer >= 1, got {steps!r}")
    if not (math.isfinite(float(cost_limit)) and float(cost_limit) >= 0):
        raise ValueError(f"cost_limit: must be a finite number >= 0, got {cost_limit!r}")
    if int(eval_episodes) < 0:
        raise ValueError(f"eval_episodes: must be >= 0, got {eval_episodes}")
    if isinstance(warmup_steps, bool) or int(warmup_steps) != warmup_steps or int(warmup_steps) < 0:
        raise ValueError(f"warmup_steps: must be an integer >= 0, got {warmup_steps!r}")
    warmup_steps = int(warmup_steps)
    steps, cost_limit, seed = int(steps), float(cost_limit), int(seed)
    cfg = ppo_config(env, cost_limit, **(ppo or {}))
    record = None
    run_info: dict[str, Any] | None = None
    if cost == "inferred":
        if run is None:
            raise ValueError("run: required with cost 'inferred' (the --out directory of pbicrl infer)")
        from pbicrl.io.runs import read_run

        record = read_run(run)
        run_info = {"path": str(Path(run).resolve()),
                    "sha256": _file_sha256([Path(run) / "summary.json", Path(run) / "chains.npz"])}
    elif run is not None:
        raise ValueError(f"run: given, but cost is {cost!r}; a run is used only with cost 'inferred'")
    factory = _CostEnvFactory(env, cost, record, mode, quantile, constraints)
    probe = factory()  # builds the cost wrapper: wrong env for the run, no selected constraint, ... fail here
    description = probe.describe() if cost == "inferred" else {"cost": cost}
    mode = probe.mode if cost == "inferred" else mode  # the default resolved by the posterior
    probe.close()
    identity = {"env": env, "cost": cost, "mode": mode if cost == "inferred" else None,
                "quantile": quantile if cost == "inferred" and mode == "penalty" else None,
                "constraints": list(constraints) if constraints else None, "cost_limit": cost_limit, "seed": seed,
                "warmup_steps": warmup_steps,
                "run_sha256": run_info["sha256"] if run_info else None, "ppo": cfg.to_dict()}
    out = Path(out_dir)
    ckpt = out / _CKPT
    if out.exists() and not out.is_dir():
        raise ValueError(f"out: {out} exists and is not a directory")
    resume = ckpt.is_file()
    if out.is_dir() and not resume and any(out.iterdir()):
        raise ValueError(f"out: {out} is not empty and holds no train-safe checkpoint; use a new directory")
    saved = None
    if resume:
        saved = _torch_load(ckpt, "out")
        if saved.get("identity") != identity:
            old = saved.get("identity") or {}
            diff = sorted(k for k in set(old) | set(identity) if old.get(k) != identity.get(k))
            raise ValueError(f"out: {out} holds a checkpoint with different settings ({', '.join(diff)}); use another "
                             "directory or the same settings to resume")
        if saved["ppo"]["num_steps"] >= steps and (out / "summary.json").is_file() and (out / _POLICY).is_file():
            summary = json.loads((out / "summary.json").read_text())
            if progress:
                print(f"train-safe: {out} already trained to {saved['ppo']['num_steps']} steps (>= {steps}); "
                      "nothing to do", file=sys.stderr)
            return summary
    out.mkdir(parents=True, exist_ok=True)

    # ---- training
    log_path = out / "progress.log"

    log = progress_logger(log_path, echo=progress)

    from pbicrl.envs._mujoco_compat import quiet_mujoco_warnings

    quiet_mujoco_warnings()
    def real_cost(c: NDArray) -> NDArray:
        return c[:, 0]

    def no_cost(c: NDArray) -> NDArray:
        return np.zeros(len(c))

    agent = PPOLagrangian(factory, lambda o, info: np.array([float(info["cost"])]), real_cost, cfg, seed=seed)
    history: list[dict[str, Any]] = []
    sessions: list[dict[str, Any]] = []
    wall_before = 0.0
    if saved is not None:
        agent.load_state_dict(saved["ppo"])
        history = list(saved.get("history", []))
        sessions = list(saved.get("sessions", []))
        wall_before = float(saved.get("wall_time_s", 0.0))
        log(f"resume: {agent.num_steps} of {steps} steps done, lambda {agent.lam:.3f}")
    else:
        log(f"new train-safe run: env {env}, cost {cost}" + (f" ({mode})" if cost == "inferred" else "")
            + f", cost limit {cost_limit:g} per episode, {steps} steps, seed {seed}")
    if agent.num_steps < warmup_steps:
        agent.set_cost_fn(no_cost)
        log(f"warm-up: no cost until {warmup_steps} steps")
    t_session = time.time()
    start_steps = agent.num_steps
    every = int(checkpoint_every) if checkpoint_every else max(cfg.n_envs * cfg.n_steps, steps // 10)

    def save(status: str) -> None:
        now = time.time()
        sess = sessions + [{"started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t_session)),
                            "wall_time_s": round(now - t_session, 1), "start_steps": start_steps,
                            "end_steps": agent.num_steps}]
        wall = wall_before + (now - t_session)
        save_checkpoint({"kind": _KIND, "identity": identity, "ppo": agent.state_dict(), "history": history,
                     "sessions": sess, "wall_time_s": wall}, ckpt)
        write_json_file(out / "budget.json", {
            "status": status, "env": env, "cost": cost, "mode": identity["mode"], "seed": seed,
            "cost_limit": cost_limit, "warmup_steps": warmup_steps, "requested_steps": steps,
            "done_steps": agent.num_steps,
            "wall_time_s": round(wall, 1), "steps_per_s": round((agent.num_steps - start_steps) / max(now - t_session, 1e-9), 1),
            "sessions": sess, "ppo": cfg.to_dict(), "run": run_info, "versions": library_versions()})

    stop = StopSignals().install()  # SIGTERM/SIGINT: checkpoint, then stop
    clock = SessionClock(save, stop, agent.num_steps, every, max_session_steps)
    last_log = {"t": time.time()}

    def on_update(p: Any, info: dict) -> bool:
        rec = {k: (float(info[k]) if info[k] is not None else None) for k in
               ("steps", "ep_return", "ep_cost", "ep_len", "lam", "lam_next", "approx_kl", "std", "seconds")}
        history.append(rec)
        if p.num_steps >= warmup_steps and p.cost_fn is no_cost:
            p.set_cost_fn(real_cost)
            log(f"warm-up over at {p.num_steps} steps: the cost is on")
        now = time.time()
        if now - last_log["t"] >= log_every_s or p.num_steps >= steps:
            rate = (p.num_steps - start_steps) / max(now - t_session, 1e-9)
            eta = max(0, steps - p.num_steps) / max(rate, 1e-9)
            log(f"steps {p.num_steps}/{steps} return {info['ep_return']:.1f} episode cost {info['ep_cost']:.2f} "
                f"(limit {cost_limit:g}) lambda {info['lam_next']:.3f} len {info['ep_len']:.0f} "
                f"({rate:.0f} steps/s, ~{eta / 60:.1f} min left)")
            last_log["t"] = now
        return clock.tick(p.num_steps)

    try:
        torch.set_num_threads(int(cfg.torch_threads))
        agent.learn(steps, callback=on_update)
        if stop.requested and agent.num_steps < steps:
            save("interrupted")
            log(f"interrupted at {agent.num_steps} steps; checkpoint written, rerun to resume")
            raise KeyboardInterrupt(f"train-safe interrupted at {agent.num_steps} steps; rerun to resume")
        save("evaluating")
    finally:
        stop.restore()
        agent.close()

    # ---- final policy, evaluation, summary
    meta = {"env": env, "cost": cost, "mode": identity["mode"], "cost_limit": cost_limit, "seed": seed,
            "steps": agent.num_steps}
    save_checkpoint({"kind": _KIND, "env": env, "ac": agent.ac.state_dict(), "obs_mean": agent.obs_rms.mean,
                 "obs_var": agent.obs_rms.var, "normalize": bool(cfg.normalize_obs), "obs_dim": agent.obs_dim,
                 "act_dim": agent.act_dim, "act_low": agent.act_low.tolist(), "act_high": agent.act_high.tolist(),
                 "hidden": list(cfg.hidden), "meta": meta}, out / _POLICY)
    evaluation = None
    if eval_episodes:
        pol = load_policy(out)
        cost_env = factory()
        try:
            evaluation = evaluate_policy(pol, env, eval_episodes, seed=10_000_019 + seed, cost_env=cost_env).to_dict()
        finally:
            cost_env.close()
        evaluation.pop("per_episode")
    tail = history[-10:]
    final = {k: float(np.nanmean([h[k] for h in tail])) if tail else None for k in ("ep_return", "ep_cost", "ep_len")}
    st = _torch_load(ckpt, "out")
    summary = {"env": env, "cost": cost, "cost_description": description, "cost_limit": cost_limit,
               "warmup_steps": warmup_steps,
               "episode_cost": "sum", "steps": agent.num_steps, "seed": seed, "lambda": agent.lam,
               "last_10_updates": final, "evaluation": evaluation,
               "evaluation_note": "deterministic policy (the Gaussian's mean), seeds 10000019 + seed + k" if evaluation else None,
               "run": run_info, "runtime_s": round(float(st["wall_time_s"]), 1), "sessions": len(st["sessions"]),
               "ppo": cfg.to_dict(), "history": history, **_limit_check(evaluation, cost_limit)}
    save("complete")
    write_json_file(out / "summary.json", summary)
    ev = "" if evaluation is None else (f"; evaluation ({eval_episodes} episodes): violation rate "
                                        f"{evaluation['violation_rate']:.3f}, true return {evaluation['true_return']:.1f}, "
                                        f"nominal return {evaluation['nominal_return']:.1f}, cost {evaluation['cost']:.2f}")
    log(f"done: {agent.num_steps} steps, lambda {agent.lam:.3f}{ev}")
    _report_limit(summary, log)
    return summary


def _limit_check(evaluation: dict[str, Any] | None, cost_limit: float) -> dict[str, Any]:
    """``cost_limit_met`` (None without an evaluation) and the numbers it rests on, for ``summary.json``."""
    if evaluation is None:
        return {"cost_limit_met": None, "cost_limit_check": None}
    c = float(evaluation.get("cost", 0.0))
    return {"cost_limit_met": bool(c <= cost_limit),
            "cost_limit_check": {"evaluation_cost": c, "cost_limit": cost_limit,
                                 "violation_rate": float(evaluation["violation_rate"]),
                                 "violating_episodes": float(evaluation["violating_episodes"])}}


def _report_limit(summary: dict[str, Any], log: Callable[[str], None]) -> None:
    """Say whether the final policy met the cost limit; warn when it did not."""
    import warnings

    from pbicrl.errors import PbicrlWarning

    chk = summary.get("cost_limit_check")
    if chk is None:
        log("cost limit: not checked (no evaluation episodes)")
        return
    line = (f"evaluation cost {chk['evaluation_cost']:.3g} per episode vs --cost-limit {chk['cost_limit']:g}; true "
            f"constraint violated in {chk['violating_episodes']:.0%} of the episodes ({chk['violation_rate']:.3g} of "
            "the steps)")
    if summary["cost_limit_met"]:
        log(f"cost limit met: {line}")
        return
    msg = (f"the final policy did NOT meet the cost limit: {line}. Train longer (--steps), raise --lagrange-lr, or "
           "lower --lr")
    log(f"WARNING: {msg}")
    warnings.warn(msg, PbicrlWarning, stacklevel=3)


__getattr__ = moved_to_cli(__name__, {"add_subcommands": "pbicrl.cli.train_safe"})  # the command line moved
