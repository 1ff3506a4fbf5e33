"""Resumable training of the ICRL benchmark's reference policies (PPO, PPO-Lagrangian with the true cost).

:func:`train_policy` trains one (task, method, seed) of :mod:`pbicrl.envs.icrl_benchmark` into a run directory
with :class:`pbicrl.baselines.ppo_lagrangian.PPOLagrangian`; rerunning it with the same arguments continues from
the last checkpoint. Command line: ``python -m pbicrl.cli.icrl_benchmark --out DIR --run TASK:METHOD:SEED:STEPS
[--run ...]`` (:mod:`pbicrl.cli.icrl_benchmark`). Methods:

``ppo``
    PPO without a cost (the multiplier stays 0; the true cost is still recorded).
``ppo_lag_true``
    PPO-Lagrangian with the benchmark's true cost (``info["cost"]``, the strict wall indicator on the post-step
    ``obs[0]``), budget 0: the expert / upper reference of the benchmark.
``ppo_lag_inferred``
    The same PPO-Lagrangian (same settings, budget 0) whose cost is pbicrl's inferred constraint:
    :class:`pbicrl.envs.inferred_cost.InferredConstraintCost` of a ``pbicrl infer`` run directory
    (``inferred_run``), in ``conservative`` mode by default (``cost_mode``), evaluated on the state each step
    reached (the post-step x and the nominal features); in ``conservative`` mode a wall's boundary must come from
    the good demonstrations of the run's own dataset (else an error: the posterior's own extreme draw can put
    the wall on the start). The true cost is still what ``curve.jsonl`` and
    ``eval.jsonl`` record (the benchmark's metrics); the inferred cost only trains. The run's identity includes
    the SHA-256 of the inference run's ``summary.json``, the mode and the resulting boundaries, so a rerun with
    another posterior is refused.
``icl``
    The project's ICL baseline (:mod:`pbicrl.baselines.icl`, :func:`~pbicrl.baselines.icl.run_icl`) on the same
    ranked demonstrations as ``ppo_lag_inferred`` (the shipped ``icrl_<task>``), of which ICL uses the good group
    (the expert's 100 episodes, their post-step x), on all five tasks (:data:`ICL_TASKS`). ICL learns its
    constraint on x and trains its own PPO-Lagrangian with it
    (:func:`icl_config`: ICL's ``default`` preset of the robot, its rounds and PPO settings, the round sizes
    scaled to ``total_steps``); the environment it trains in is the benchmark's with ``info["cost"]`` removed.
    The run directory has the layout below (``config.json``, ``curve.jsonl``, ``eval.jsonl``, ``progress.json``,
    ``done.json``; the evaluations are the same :func:`_evaluate` with the true cost, every ``eval_every`` x
    10,240 steps and at the end), plus ICL's own files (``checkpoint.pt`` is ICL's resume point; ``summary.json``
    with the learned constraint's location and CMSE, ``progress.log``, ``budget.json``, ``constraint.pt``,
    ``constraint_grid.npz``). No ``best.pt``.

Hyperparameters follow the benchmark's expert configs (``train_ppo_lag_*.yaml``, note section 3) where our PPO has
the same knob: 5 environments x 2048 steps per rollout, [64, 64] tanh networks, gamma 0.99 (reward and cost),
the task's learning rate, epochs, minibatch size, GAE lambda, clip, target KL, initial multiplier :math:`\\nu_0`
(also its lower bound) and multiplier learning rate, entropy 0, value coefficient 0.5, gradient clip 0.5,
initial log std 0 (SB3's default). As the benchmark, the multiplier :math:`\\nu = \\mathrm{softplus}(\\theta)` takes
one Adam step per rollout on the rollout's mean raw per-step cost (budget 0) and never falls below :math:`\\nu_0`
(``lagrange_optimizer="adam"``, ``lagrange_min``), and the cost critic sees costs divided by the running std of
the discounted cost return (``scale_cost``). Differences (recorded in ``config.json`` and
``docs/benchmarks/icrl/README.md``):

* the cost enters the clipped surrogate through the combined advantage :math:`(A_r - \\nu A_c)/(1+\\nu)`; the
  benchmark clips the reward surrogate only and adds :math:`\\nu\\,\\mathrm{mean}(A_c \\cdot \\text{ratio})` unclipped
  (both scaled by :math:`1/(1+\\nu)`);
* one GAE lambda serves reward and cost (Swimmer's cost lambda 0.95 becomes 0.9);
* the target KL is checked after each epoch on the epoch's mean KL, against 1.5 x the config's value (SB3 stops
  within an epoch when the KL exceeds 1.5 x ``target_kl``);
* gradients are clipped per network (policy, reward critic, cost critic) rather than jointly;
* time-limit ends are bootstrapped with the critics (the original treated them as terminal);
* the environments are not reset at every 200k-step "iteration" (there are no iterations here);
* the Biased Pendulum's and the Blocked Swimmer's initial multiplier (and floor) :math:`\\nu_0` is 10 and 30 instead
  of 0.1 and 1 (:data:`BENCHMARK_NU0` keeps the benchmark's): with the benchmark's the policy first learns the
  reward's optimum beyond the wall, the multiplier (one Adam step of at most about its learning rate per rollout)
  reaches the tens only after hundreds of rollouts, and by then the policy no longer leaves: violation rate 1.00
  after the benchmark's own 10 M (pendulum) and 5 M (swimmer) steps (``docs/benchmarks/icrl/README.md``).

Run directory (``<out>/<task>/<method>/seed<k>/``):

``config.json``
    task, method, seed, PPO config, evaluation settings (written once; a rerun with other settings is refused).
``checkpoint.pt``
    resume point, written atomically every ``checkpoint_every`` updates (tensors and plain values only, read with
    ``torch.load(weights_only=True)``), with the byte lengths of the two logs at that moment, so that a resumed run
    first cuts the logs back to them and no episode is logged twice.
``curve.jsonl``
    one line per finished training episode (stochastic policy), exactly the note's section 2 per-episode metrics:
    ``reward`` (sum of rewards), ``reward_nc`` (sum of rewards before the first step with cost 1; equals
    ``reward`` when nothing is violated), ``constraint`` (1 if any step violated), plus ``cost_sum``,
    ``length``, ``x_min``, ``x_max``, ``steps`` (environment steps at the end of the update it finished in) and
    ``update``.
``eval.jsonl``
    every ``eval_every`` updates and at the end: ``eval_episodes`` stochastic-policy episodes on fresh
    environments (their per-episode metrics and means; ``violation_rate`` = mean of ``constraint``).
``best.pt``
    the agent at the evaluation with the highest mean ``reward_nc`` (the benchmark's ``best_nominal_model``).
``progress.json``, ``done.json``
    the latest summary; written when the target number of steps is reached.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "make_task_env",
    "BENCHMARK_NU0",
    "CHECKPOINT",
    "ICL_TASKS",
    "METHODS",
    "CheckpointPolicy",
    "EpisodeRecorder",
    "RunBusyError",
    "demonstrations_dataset",
    "episode_metrics",
    "expert_config",
    "icl_config",
    "load_run_checkpoint",
    "rollout_episodes",
    "selection",
    "train_policy",
]

CHECKPOINT = "checkpoint.pt"
METHODS: tuple[str, ...] = ("ppo", "ppo_lag_true", "ppo_lag_inferred", "icl")
ICL_TASKS: dict[str, str] = {"halfcheetah": "icrl_halfcheetah", "ant": "icrl_ant", "walker": "icrl_walker",
                             "pendulum": "icrl_pendulum", "swimmer": "icrl_swimmer"}
"""Tasks the ``icl`` method runs on -> their ICL environment (:func:`pbicrl.baselines.icl.icl_env`), which is also
the name of the shipped dataset whose good group ICL learns from."""
_ROLLOUT = 5 * 2048  # one update of the benchmark's PPO (expert_config): the unit of eval_every for icl too
_LAGRANGIAN = ("ppo_lag_true", "ppo_lag_inferred")
_EVAL_EPISODES = {"pendulum": 100}  # the note: 10 evaluation episodes per iteration, 100 for the pendulum

# The expert configs of note section 3: lr, epochs, minibatch, GAE lambda (reward), clip, target KL, nu_0, nu lr.
_EXPERT: dict[str, dict[str, float]] = {
    "halfcheetah": dict(lr=3e-4, n_epochs=10, minibatch_size=64, gae_lambda=0.95, clip=0.2, target_kl=0.01,
                        nu0=1.0, nu_lr=0.1),
    "ant": dict(lr=3e-5, n_epochs=20, minibatch_size=128, gae_lambda=0.9, clip=0.4, target_kl=0.02, nu0=0.1,
                nu_lr=0.05),
    "pendulum": dict(lr=1e-4, n_epochs=20, minibatch_size=128, gae_lambda=0.9, clip=0.4, target_kl=0.02,
                     nu0=10.0, nu_lr=0.05),
    "walker": dict(lr=3e-4, n_epochs=10, minibatch_size=64, gae_lambda=0.95, clip=0.2, target_kl=0.01, nu0=1.0,
                   nu_lr=0.1),
    "swimmer": dict(lr=3e-4, n_epochs=20, minibatch_size=128, gae_lambda=0.9, clip=0.4, target_kl=0.01, nu0=30.0,
                    nu_lr=0.1),
}
BENCHMARK_NU0: dict[str, float] = {"halfcheetah": 1.0, "ant": 0.1, "pendulum": 0.1, "walker": 1.0, "swimmer": 1.0}
"""The benchmark's own initial multiplier per task; ``_EXPERT`` departs from it for the pendulum and the swimmer
(module docstring), and ``config_overrides={"lagrange_init": v, "lagrange_min": v}`` restores it."""


def expert_config(task: str, method: str) -> Any:
    """The :class:`~pbicrl.baselines.ppo_lagrangian.PPOLagConfig` of ``method`` on ``task`` (see the module
    docstring for what differs from the benchmark's expert config)."""
    from pbicrl.baselines.ppo_lagrangian import PPOLagConfig
    from pbicrl.envs.icrl_benchmark import icrl_task

    name = icrl_task(task).name
    _check_method(method)
    if method == "icl":
        raise ValueError("method: icl trains with ICL's own PPO settings (icl_config), not expert_config")
    h = _EXPERT[name]
    lag = method in _LAGRANGIAN
    return PPOLagConfig(
        n_envs=5, n_steps=2048, gamma=0.99, cost_gamma=0.99, gae_lambda=h["gae_lambda"], clip=h["clip"],
        lr=h["lr"], n_epochs=int(h["n_epochs"]), minibatch_size=int(h["minibatch_size"]), hidden=(64, 64),
        init_log_std=0.0, ent_coef=0.0, vf_coef=0.5, max_grad_norm=0.5, target_kl=1.5 * h["target_kl"],
        cost_budget=0.0, lagrange_lr=h["nu_lr"], lagrange_init=h["nu0"] if lag else 0.0,
        lagrange_min=h["nu0"] if lag else 0.0, lagrange_max=100.0, normalize_obs=True, scale_reward=True,
        torch_threads=1, episode_cost="step", lagrange_optimizer="adam" if lag else "sgd", scale_cost=lag,
    ).validate()


def icl_config(task: str, total_steps: int, budget: str = "default",
               overrides: dict[str, Any] | None = None) -> Any:
    """ICL's settings (:class:`pbicrl.baselines.icl.ICLConfig`) for the ``icl`` method on ``task``.

    ICL's preset ``budget`` of the task's ICL environment (``default``: HalfCheetah 8 rounds, 1 M + 7 x 0.5 M =
    4.5 M PPO steps; Ant 6 rounds, 1 M + 5 x 0.3 M = 2.5 M; PPO 4 environments x 512 steps, ICL's own
    PPO-Lagrangian on the expected discounted learned cost, budget beta = 1). When ``total_steps`` differs from
    the preset's total, the number of rounds is kept and the rounds are scaled: later rounds to
    ``round(round_steps * total_steps / preset_total)`` (a whole number of PPO rollouts, at least one), the first
    round takes the rest. ``overrides`` (ICLConfig fields; ``ppo`` a dict of PPO fields) apply last.

    Raises
    ------
    ValueError
        A task without ICL environment (naming :data:`ICL_TASKS`), an unknown preset or option, or a
        ``total_steps`` too small for the rounds.
    """
    from pbicrl.baselines.icl import ICLConfig, icl_preset
    from pbicrl.envs.icrl_benchmark import icrl_task

    name = icrl_task(task).name
    if name not in ICL_TASKS:
        raise ValueError(f"task: method icl runs on {sorted(ICL_TASKS)} only (the tasks with ICL environments), "
                         f"not {name!r}")
    if int(total_steps) != total_steps or total_steps < 1:
        raise ValueError(f"total_steps: must be an integer >= 1, got {total_steps!r}")
    cfg = icl_preset(budget, ICL_TASKS[name])
    if int(total_steps) != cfg.total_steps:
        rollout = cfg.ppo.n_envs * cfg.ppo.n_steps
        later = max(rollout, int(round(cfg.round_steps * total_steps / cfg.total_steps / rollout)) * rollout)
        first = int(total_steps) - (cfg.rounds - 1) * later
        if first < rollout:
            raise ValueError(f"total_steps: {total_steps} is too small for ICL's {cfg.rounds} rounds of at least "
                             f"{rollout} steps each (preset {budget!r})")
        cfg = ICLConfig.from_dict({**cfg.to_dict(), "first_round_steps": first, "round_steps": later})
    if overrides:
        base, over = cfg.to_dict(), dict(overrides)
        if "ppo" in over:
            base["ppo"] = {**base["ppo"], **dict(over.pop("ppo"))}
        cfg = ICLConfig.from_dict({**base, **over})
    return cfg


def _check_method(method: str) -> None:
    if method not in METHODS:
        raise ValueError(f"method: unknown method {method!r}; expected one of {list(METHODS)}")


def selection(field: str, given: Sequence[str] | None, default: Sequence[str], *,
              canonical: Callable[[str], str] | None = None) -> list[str]:
    """The names picked for ``field`` (``tasks``, ``methods``), checked.

    An empty ``given`` is refused rather than read as "all" (``--tasks ","`` would otherwise start every run),
    as are names listed twice.

    Parameters
    ----------
    field : str
        The option's name, used in the error messages.
    given : sequence of str or None
        The user's names; None for all of ``default``.
    default : sequence of str
        Every name, in order.
    canonical : callable, optional
        Maps a name to its canonical spelling and raises ``ValueError`` for an unknown one (a task's
        ``pbicrl/...`` id to its short name). Without it a name must be in ``default``.

    Returns
    -------
    list of str
        The canonical names, in the order given.

    Raises
    ------
    ValueError
        Empty, unknown or repeated names.
    """
    if given is None:
        return list(default)
    given = list(given)
    if not given:
        raise ValueError(f"{field}: none given; leave it out for all of {list(default)}")
    if canonical is None:
        bad = [x for x in given if x not in default]
        if bad:
            raise ValueError(f"{field}: unknown {bad}; expected some of {list(default)}")
        names = given
    else:
        names = [canonical(x) for x in given]
    twice = sorted({x for x in names if names.count(x) > 1})
    if twice:
        raise ValueError(f"{field}: listed twice: {twice}")
    return names


def episode_metrics(rewards: Sequence[float], costs: Sequence[float]) -> dict[str, float | int]:
    """The benchmark's per-episode metrics (note section 2) of one episode's per-step rewards and costs.

    Returns
    -------
    dict
        ``reward`` = :math:`\\sum_t r_t`; ``reward_nc`` = the sum over the steps *before* the first step with a
        positive cost (the violating step excluded; equals ``reward`` without a violation); ``constraint`` = 1 if
        any step has a positive cost, else 0; ``cost_sum``; ``length``.
    """
    r = np.asarray(rewards, dtype=np.float64).reshape(-1)
    c = np.asarray(costs, dtype=np.float64).reshape(-1)
    if r.shape != c.shape:
        raise ValueError(f"episode_metrics: {r.size} rewards but {c.size} costs")
    hit = np.flatnonzero(c > 0)
    first = int(hit[0]) if hit.size else r.size
    return {"reward": float(r.sum()), "reward_nc": float(r[:first].sum()), "constraint": int(hit.size > 0),
            "cost_sum": float(c.sum()), "length": int(r.size)}


def _make_recorder_class() -> type:
    import gymnasium as gym

    class _EpisodeRecorder(gym.Wrapper):
        """Appends :func:`episode_metrics` (plus ``x_min``, ``x_max`` of ``obs[0]``) of every finished episode to
        ``sink``; the cost is ``info["cost"]``."""

        def __init__(self, env: Any, sink: list[dict[str, Any]]) -> None:
            super().__init__(env)
            self.sink = sink
            self._r: list[float] = []
            self._c: list[float] = []
            self._x: list[float] = []

        def reset(self, **kwargs: Any) -> Any:
            self._r, self._c, self._x = [], [], []
            return self.env.reset(**kwargs)

        def step(self, action: Any) -> Any:
            obs, r, term, trunc, info = self.env.step(action)
            self._r.append(float(r))
            self._c.append(float(info["cost"]))
            self._x.append(float(np.asarray(obs).reshape(-1)[0]))
            if term or trunc:
                m = episode_metrics(self._r, self._c)
                m.update(x_min=min(self._x), x_max=max(self._x))
                self.sink.append(m)
                self._r, self._c, self._x = [], [], []
            return obs, r, term, trunc, info

    return _EpisodeRecorder


_RECORDER: type | None = None


def EpisodeRecorder(env: Any, sink: list[dict[str, Any]]) -> Any:  # noqa: N802 - a class factory (lazy gymnasium)
    """Wrap ``env`` so that each finished episode's :func:`episode_metrics` (and ``x_min``/``x_max``) is appended
    to ``sink``."""
    global _RECORDER
    if _RECORDER is None:
        _RECORDER = _make_recorder_class()
    return _RECORDER(env, sink)


def make_task_env(task: str) -> Any:
    """The Gymnasium environment of an ICRL benchmark task (its registered id, default settings)."""
    import gymnasium as gym

    from pbicrl.envs import register_envs
    from pbicrl.envs.icrl_benchmark import icrl_task

    register_envs()
    return gym.make(icrl_task(task).env_id)


def _truncate(path: Path, size: int) -> None:
    if path.exists() and path.stat().st_size > size:
        with open(path, "r+b") as fh:
            fh.truncate(size)


def _drain_episodes(sink: list[dict[str, Any]], state: dict[str, Any], ag: Any, curve: Path,
                    recent: list[dict[str, Any]]) -> None:
    """Move the episodes finished since the last update from ``sink`` to ``curve.jsonl`` (numbered, with the
    agent's step and update counts) and to ``recent`` (the last 100, for the progress line)."""
    rows = []
    for m in sink:
        state["episodes"] = int(state["episodes"]) + 1
        rows.append({"episode": state["episodes"], "steps": ag.num_steps, "update": ag.num_updates, **m})
    sink.clear()
    if rows:
        _append_lines(curve, rows)
        recent.extend(rows)
        del recent[:-100]


def _append_lines(path: Path, rows: list[dict[str, Any]]) -> int:
    """Append JSON lines, flush to disk; return the file's new size."""
    with open(path, "a", encoding="utf-8") as fh:
        for row in rows:
            fh.write(json.dumps(row, allow_nan=True) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    return path.stat().st_size


def load_run_checkpoint(path: Path) -> dict[str, Any]:
    """Read a run's checkpoint with ``torch.load(weights_only=True)``; errors name the file."""
    from pbicrl.baselines.session import load_safely

    obj = load_safely(path, "out", "delete it to start the run afresh")
    if not isinstance(obj, dict) or "agent" not in obj:
        raise ValueError(f"out: {path} is not a checkpoint of pbicrl.experiments.icrl_benchmark (no 'agent')")
    return obj


def _evaluate(agent: Any, task: str, n_episodes: int, seed: int) -> dict[str, Any]:
    """``n_episodes`` stochastic-policy episodes (seeded) with the benchmark's per-episode metrics."""
    import torch

    sink: list[dict[str, Any]] = []
    env = EpisodeRecorder(make_task_env(task), sink)
    gen = torch.Generator().manual_seed(seed)
    try:
        for k in range(n_episodes):
            obs, _ = env.reset(seed=seed + k)
            while True:
                a = agent.act(np.asarray(obs, dtype=np.float64)[None], deterministic=False, generator=gen)[0]
                obs, _, term, trunc, _ = env.step(a)
                if term or trunc:
                    break
    finally:
        env.close()
    keys = ("reward", "reward_nc", "constraint", "cost_sum", "length")
    means = {k: float(np.mean([m[k] for m in sink])) for k in keys}
    means["violation_rate"] = means.pop("constraint")
    return {**means, "episodes": sink}


def _last_mean(rows: list[dict[str, Any]], key: str, n: int = 100) -> float | None:
    """Mean of ``key`` over the last ``n`` rows (None without rows, so the JSON stays strict)."""
    vals = [r[key] for r in rows[-n:]]
    return float(np.mean(vals)) if vals else None


def _fmt(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"


def train_policy(task: str, method: str, seed: int, out: str | os.PathLike[str], total_steps: int, *,
                 checkpoint_every: int = 2, eval_every: int = 10, eval_episodes: int | None = None,
                 config_overrides: dict[str, Any] | None = None, log: Callable[[str], None] | None = print,
                 max_seconds: float | None = None, inferred_run: str | os.PathLike[str] | None = None,
                 cost_mode: str = "conservative", icl_budget: str = "default") -> Path:
    """Train (or continue training) one policy of the ICRL benchmark.

    Parameters
    ----------
    task : str
        ``halfcheetah``, ``ant``, ``pendulum``, ``walker``, ``swimmer`` (or a ``pbicrl/...`` id).
    method : {"ppo", "ppo_lag_true", "ppo_lag_inferred", "icl"}
    seed : int
    out : path
        Root of the runs; the run directory is ``out/<task>/<method>/seed<seed>``.
    total_steps : int
        Target number of environment steps (a total: a rerun continues to it; a larger value extends a finished
        run).
    checkpoint_every, eval_every : int
        Updates (rollouts of 5 x 2048 steps by default) between checkpoints and between evaluations. ``icl``:
        ``eval_every`` x 10,240 environment steps between evaluations; checkpoints follow ICL's preset
        (``checkpoint_every`` steps, and after every round), ``checkpoint_every`` here is not used.
    eval_episodes : int, optional
        Evaluation episodes (default 10; 100 for the pendulum, as the benchmark).
    config_overrides : dict, optional
        Fields of :func:`expert_config` to replace (e.g. ``n_steps`` for short tests); part of the run's identity.
        ``icl``: fields of :class:`~pbicrl.baselines.icl.ICLConfig` (``ppo`` a dict), see :func:`icl_config`.
    log : callable or None
        Progress lines (``print`` by default).
    max_seconds : float, optional
        Stop (after a checkpoint) once this much wall time has passed in this call.
    inferred_run : path, optional
        ``ppo_lag_inferred`` only (and required there): the ``pbicrl infer`` run directory whose posterior is the
        cost.
    cost_mode : str
        ``ppo_lag_inferred``: the :class:`~pbicrl.envs.inferred_cost.InferredConstraintCost` mode (default
        ``conservative``).
    icl_budget : str
        ``icl``: ICL's preset (``default``; ``smoke`` for tests), see :func:`icl_config`.

    Returns
    -------
    Path
        The run directory.
    """
    from pbicrl._atomic import write_json
    from pbicrl.baselines.icl.checkpoint import save_checkpoint
    from pbicrl.baselines.ppo_lagrangian import PPOLagrangian
    from pbicrl.envs.icrl_benchmark import icrl_task

    spec = icrl_task(task)
    _check_method(method)
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed: must be an integer >= 0, got {seed!r}")
    if int(total_steps) != total_steps or total_steps < 1:
        raise ValueError(f"total_steps: must be an integer >= 1, got {total_steps!r}")
    for name, v in (("checkpoint_every", checkpoint_every), ("eval_every", eval_every)):
        if int(v) != v or v < 1:
            raise ValueError(f"{name}: must be an integer >= 1, got {v!r}")
    n_eval = int(eval_episodes if eval_episodes is not None else _EVAL_EPISODES.get(spec.name, 10))
    if n_eval < 1:
        raise ValueError(f"eval_episodes: must be >= 1, got {eval_episodes!r}")
    if method == "icl":
        if inferred_run is not None:
            raise ValueError("inferred_run: only for method ppo_lag_inferred, not 'icl'")
        return _train_icl(spec.name, int(seed), Path(out), int(total_steps), eval_every=int(eval_every),
                          n_eval=n_eval, budget=icl_budget, overrides=config_overrides, log=log,
                          max_seconds=max_seconds)
    cfg = expert_config(spec.name, method)
    if config_overrides:
        unknown = set(config_overrides) - set(cfg.__dataclass_fields__)
        if unknown:
            raise ValueError(f"config_overrides: unknown PPO options {sorted(unknown)}")
        cfg = replace(cfg, **config_overrides).validate()
    say = log or (lambda _s: None)
    inferred = _inferred_cost(spec.name, method, inferred_run, cost_mode)

    run = Path(out) / spec.name / method / f"seed{int(seed)}"
    run.mkdir(parents=True, exist_ok=True)
    identity = {"task": spec.name, "env_id": spec.env_id, "method": method, "seed": int(seed), "ppo": cfg.to_dict(),
                "eval_episodes": n_eval, "eval_every": int(eval_every)}
    if inferred is not None:
        identity["inferred_cost"] = inferred[1]
    lock = run / "lock"
    _acquire(lock)  # before config.json: a second process is refused before it writes anything
    try:
        _write_identity(run, identity, {
            **({"inferred_run": str(Path(inferred_run).resolve()),  # type: ignore[arg-type]
                "inferred_boundary_source": inferred[0].boundary_source} if inferred else {}),
            "note": "ICRL benchmark reference policy; see pbicrl.experiments.icrl_benchmark"})
        sink: list[dict[str, Any]] = []
        coord_fn = lambda o, info: np.asarray([o[0]], dtype=np.float64)  # noqa: E731
        if method == "ppo_lag_true":
            cost_fn = lambda xs: spec.cost(np.asarray(xs)[:, 0])  # noqa: E731
        elif inferred is not None:
            icc = inferred[0]
            coord_fn = lambda o, info: np.concatenate([[o[0]], np.asarray(info["features"], dtype=np.float64)])  # noqa: E731
            cost_fn = lambda cs: icc.costs(features=np.asarray(cs)[:, 1:], states=np.asarray(cs)[:, :1])  # noqa: E731
        else:
            cost_fn = lambda xs: np.zeros(np.asarray(xs).shape[0])  # noqa: E731
        agent = PPOLagrangian(lambda: EpisodeRecorder(make_task_env(spec.name), sink), coord_fn, cost_fn, cfg,
                              seed=int(seed), fused_optimizer=True)
        curve, evals = run / "curve.jsonl", run / "eval.jsonl"
        state: dict[str, Any] = {"curve_bytes": 0, "eval_bytes": 0, "episodes": 0, "best_reward_nc": -math.inf,
                                 "wall_s": 0.0, "evals": 0}
        ck = run / CHECKPOINT
        if ck.exists():
            obj = load_run_checkpoint(ck)
            agent.load_state_dict(obj["agent"])
            state.update({k: obj[k] for k in state if k in obj})
            say(f"[{spec.name}/{method}/seed{seed}] resumed at {agent.num_steps} steps ({state['episodes']} episodes)")
        _truncate(curve, int(state["curve_bytes"]))
        _truncate(evals, int(state["eval_bytes"]))
        if not curve.exists():
            curve.touch()
        if not evals.exists():
            evals.touch()
        if agent.num_steps >= total_steps and (run / "done.json").exists():
            say(f"[{spec.name}/{method}/seed{seed}] already done ({agent.num_steps} steps)")
            return run

        t_start = time.perf_counter()
        wall0 = float(state["wall_s"])
        recent: list[dict[str, Any]] = []

        def save(final: bool = False) -> None:
            state["curve_bytes"] = curve.stat().st_size
            state["eval_bytes"] = evals.stat().st_size
            state["wall_s"] = wall0 + time.perf_counter() - t_start
            save_checkpoint({"agent": agent.state_dict(), **state}, ck)

        def evaluate() -> None:
            res = _evaluate(agent, spec.name, n_eval, seed=10_000 * (int(seed) + 1) + 1000 * int(state["evals"]))
            state["evals"] = int(state["evals"]) + 1
            row = {"update": agent.num_updates, "steps": agent.num_steps, "lam": agent.lam, **res}
            _append_lines(evals, [row])
            if res["reward_nc"] > state["best_reward_nc"]:
                state["best_reward_nc"] = res["reward_nc"]
                save_checkpoint({"agent": agent.state_dict(), "eval": {k: v for k, v in row.items()
                                                                        if k != "episodes"}}, run / "best.pt")
            say(f"[{spec.name}/{method}/seed{seed}] eval @ {agent.num_steps}: reward {res['reward']:.1f} "
                f"reward_nc {res['reward_nc']:.1f} violation_rate {res['violation_rate']:.2f}")

        def callback(ag: Any, info: dict[str, Any]) -> bool:
            _drain_episodes(sink, state, ag, curve, recent)
            if ag.num_updates % eval_every == 0:
                evaluate()
            stop = max_seconds is not None and time.perf_counter() - t_start > max_seconds
            if ag.num_updates % checkpoint_every == 0 or stop or ag.num_steps >= total_steps:
                save()
                elapsed = time.perf_counter() - t_start
                write_json(run / "progress.json", {
                    "steps": ag.num_steps, "updates": ag.num_updates, "episodes": state["episodes"], "lam": ag.lam,
                    "last100_reward": _last_mean(recent, "reward"), "last100_reward_nc": _last_mean(recent, "reward_nc"),
                    "last100_violation_rate": _last_mean(recent, "constraint"), "wall_s": state["wall_s"],
                    "seconds_this_call": elapsed, "total_steps_target": int(total_steps)})
                say(f"[{spec.name}/{method}/seed{seed}] {ag.num_steps} steps, lam {ag.lam:.3f}, last-100 reward "
                    f"{_fmt(_last_mean(recent, 'reward'))} reward_nc {_fmt(_last_mean(recent, 'reward_nc'))} viol "
                    f"{_fmt(_last_mean(recent, 'constraint'))}, kl {info['approx_kl']:.4f} ep {info['epochs']}, "
                    f"{info['seconds']:.1f}s/update")
            return not stop

        agent.learn(int(total_steps), callback=callback)
        if agent.num_steps >= total_steps:
            if agent.num_updates % eval_every != 0:
                evaluate()
            save(final=True)
            write_json(run / "done.json", {"steps": agent.num_steps, "updates": agent.num_updates,
                                           "episodes": state["episodes"], "wall_s": state["wall_s"],
                                           "best_eval_reward_nc": state["best_reward_nc"]})
            say(f"[{spec.name}/{method}/seed{seed}] done: {agent.num_steps} steps in {state['wall_s']:.0f}s")
        agent.close()
        return run
    finally:
        lock.unlink(missing_ok=True)


def _write_identity(run: Path, identity: dict[str, Any], extra: dict[str, Any]) -> None:
    """Write ``run/config.json`` (``identity``, the pbicrl version and ``extra``), or check that an existing one
    has the same ``identity`` (else a ValueError naming the fields that differ)."""
    from pbicrl import __version__
    from pbicrl._atomic import write_json

    cfg_path = run / "config.json"
    if cfg_path.exists():
        old = json.loads(cfg_path.read_text(encoding="utf-8"))
        old_id = {k: old.get(k) for k in identity}
        if old_id != json.loads(json.dumps(identity)):
            diff = sorted(k for k in identity if old_id.get(k) != json.loads(json.dumps(identity[k])))
            raise ValueError(f"out: {run} holds a run with other settings ({', '.join(diff)}); use another --out "
                             "or delete it")
    else:
        write_json(cfg_path, {**identity, "pbicrl_version": __version__, **extra})


def _keep_rows_until(path: Path, steps: int) -> list[dict[str, Any]]:
    """Cut a JSON-lines log back to its rows with ``steps <= steps`` (those logged before the checkpoint a run
    resumes from) and return them; creates the file when missing."""
    from pbicrl._atomic import write_text

    if not path.exists():
        path.touch()
        return []
    rows = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    kept = [r for r in rows if int(r.get("steps", 0)) <= int(steps)]
    if len(kept) != len(rows):
        write_text(path, "".join(json.dumps(r, allow_nan=True) + "\n" for r in kept))
    return kept


def _train_icl(task: str, seed: int, out: Path, total_steps: int, *, eval_every: int, n_eval: int, budget: str,
               overrides: dict[str, Any] | None, log: Callable[[str], None] | None,
               max_seconds: float | None) -> Path:
    """The ``icl`` method of :func:`train_policy` (see the module docstring): :func:`run_icl` in the run
    directory, with the benchmark's logs written from its PPO updates and the final policy evaluated as the
    other methods' are."""
    import hashlib
    from dataclasses import replace as dc_replace

    from pbicrl._atomic import write_json
    from pbicrl.baselines.icl import ICRLFactory, expert_coordinates, icl_env, icrl_coord, run_icl
    from pbicrl.baselines.icl.checkpoint import CHECKPOINT as ICL_CHECKPOINT
    from pbicrl.baselines.icl.checkpoint import load_checkpoint
    from pbicrl.baselines.ppo_lagrangian import PPOLagrangian
    from pbicrl.envs.icrl_benchmark import icrl_task
    from pbicrl.inference.data import load_dataset, resolve_dataset_path

    spec = icrl_task(task)
    cfg = icl_config(spec.name, total_steps, budget, overrides)
    data = ICL_TASKS[spec.name]
    ds = load_dataset(data)
    expert = expert_coordinates(ds, group=1, n=None)
    say = log or (lambda _s: None)
    tag = f"[{spec.name}/icl/seed{seed}]"

    run = out / spec.name / "icl" / f"seed{seed}"
    run.mkdir(parents=True, exist_ok=True)
    identity = {"task": spec.name, "env_id": spec.env_id, "method": "icl", "seed": seed, "icl": cfg.to_dict(),
                "icl_budget": budget, "expert_data": data,
                "expert_data_sha256": hashlib.sha256(Path(resolve_dataset_path(data)).read_bytes()).hexdigest(),
                "expert_group": 1, "n_expert": len(expert), "eval_episodes": n_eval, "eval_every": eval_every}
    lock = run / "lock"
    _acquire(lock)
    try:
        _write_identity(run, identity, {
            "note": "ICRL benchmark: the ICL baseline (pbicrl.baselines.icl) on the good group of the task's "
                    "ranked demonstrations; checkpoint.pt, summary.json, budget.json, progress.log are ICL's own "
                    "files; see pbicrl.experiments.icrl_benchmark"})
        curve, evals, ck = run / "curve.jsonl", run / "eval.jsonl", run / ICL_CHECKPOINT
        if (run / "done.json").exists() and (run / "summary.json").exists():
            say(f"{tag} already done")
            return run
        done_steps, wall0 = 0, 0.0
        if ck.exists():
            st = load_checkpoint(ck)
            done_steps, wall0 = int(st["ppo"]["num_steps"]), float(st["state"].get("wall_time_s", 0.0))
        rows = _keep_rows_until(curve, done_steps)
        ev_rows = _keep_rows_until(evals, done_steps)
        state: dict[str, Any] = {"episodes": len(rows), "evals": len(ev_rows), "stopped": False}
        recent: list[dict[str, Any]] = rows[-100:]
        interval = int(eval_every) * _ROLLOUT
        t_start = time.perf_counter()

        def evaluate(agent: Any) -> None:
            res = _evaluate(agent, spec.name, n_eval, seed=10_000 * (seed + 1) + 1000 * int(state["evals"]))
            state["evals"] = int(state["evals"]) + 1
            _append_lines(evals, [{"update": agent.num_updates, "steps": agent.num_steps, "lam": agent.lam, **res}])
            say(f"{tag} eval @ {agent.num_steps}: reward {res['reward']:.1f} reward_nc {res['reward_nc']:.1f} "
                f"violation_rate {res['violation_rate']:.2f}")

        sink: list[dict[str, Any]] = []

        def on_update(ag: Any, info: dict[str, Any]) -> bool:
            _drain_episodes(sink, state, ag, curve, recent)
            rollout = ag.cfg.n_envs * ag.cfg.n_steps
            if ag.num_steps // interval > (ag.num_steps - rollout) // interval:
                evaluate(ag)
            write_json(run / "progress.json", {
                "steps": ag.num_steps, "updates": ag.num_updates, "episodes": state["episodes"], "lam": ag.lam,
                "last100_reward": _last_mean(recent, "reward"), "last100_reward_nc": _last_mean(recent, "reward_nc"),
                "last100_violation_rate": _last_mean(recent, "constraint"),
                "wall_s": wall0 + time.perf_counter() - t_start, "seconds_this_call": time.perf_counter() - t_start,
                "total_steps_target": cfg.total_steps})
            if max_seconds is not None and time.perf_counter() - t_start > max_seconds:
                state["stopped"] = True
                return False
            return True

        icl_spec = icl_env(data)
        icl_spec = dc_replace(icl_spec, make=ICRLFactory(spec.name, wrap=lambda e: EpisodeRecorder(e, sink)),
                              make_eval=ICRLFactory(spec.name))
        say(f"{tag} ICL: {cfg.rounds} rounds, {cfg.total_steps} PPO steps, {len(expert)} expert episodes of {data}"
            + (f"; resuming at {done_steps} steps" if done_steps else ""))
        try:
            summary = run_icl(icl_spec, expert, cfg, run, seed=seed, progress=log is not None, on_update=on_update)
        except KeyboardInterrupt:
            if state["stopped"]:  # max_seconds: checkpointed, resumable
                say(f"{tag} stopped after {max_seconds} s (checkpoint written)")
                return run
            raise

        # the final policy, evaluated as the other methods' are (stochastic, fresh environments, the true cost)
        t_eval = time.perf_counter()
        final = load_checkpoint(ck)["ppo"]
        agent = PPOLagrangian(ICRLFactory(spec.name), icrl_coord, lambda cs: np.zeros(len(cs)),
                              dc_replace(cfg.ppo, n_envs=1), seed=seed)
        try:
            agent.load_state_dict(final)
        finally:
            agent.close()
        last = _keep_rows_until(evals, agent.num_steps)
        if not last or int(last[-1]["steps"]) != agent.num_steps:
            evaluate(agent)
        wall = float(summary.get("runtime_s", 0.0)) + time.perf_counter() - t_eval
        write_json(run / "done.json", {
            "steps": agent.num_steps, "updates": agent.num_updates, "episodes": state["episodes"], "wall_s": wall,
            "icl_location": summary.get("location"), "true_location": summary.get("true_location"),
            "cmse_location": summary.get("cmse_location"), "cmse_grid": summary.get("cmse_grid"),
            "rounds": cfg.rounds})
        say(f"{tag} done: {agent.num_steps} steps in {wall:.0f} s; ICL's wall at {summary.get('location')} "
            f"(true x {'<' if spec.side == 'behind' else '>'} {spec.wall:g})")
        return run
    finally:
        lock.unlink(missing_ok=True)


def _inferred_cost(task: str, method: str, run_dir: str | os.PathLike[str] | None,
                   mode: str) -> tuple[Any, dict[str, Any]] | None:
    """``ppo_lag_inferred``: the :class:`InferredConstraintCost` of ``run_dir`` on ``task`` and its identity
    (summary hash, mode, used constraints, conservative boundaries); None for the other methods."""
    if method != "ppo_lag_inferred":
        if run_dir is not None:
            raise ValueError(f"inferred_run: only for method ppo_lag_inferred, not {method!r}")
        return None
    if run_dir is None:
        raise ValueError("inferred_run: method ppo_lag_inferred needs the run directory of pbicrl infer "
                         "(--inferred-run)")
    from pbicrl.envs.inferred_cost import MODES, InferredConstraintCost

    if mode not in MODES:
        raise ValueError(f"cost_mode: expected one of {', '.join(MODES)}, got {mode!r}")
    summary = Path(run_dir) / "summary.json"
    if not summary.is_file():
        raise ValueError(f"inferred_run: {run_dir} has no summary.json (not a pbicrl infer run directory)")
    env = make_task_env(task)
    try:
        icc = InferredConstraintCost(env, run_dir, mode=mode)
    finally:
        env.close()
    fallback = {k: v for k, v in icc.boundary_source.items() if not v.startswith("the good demonstrations")}
    if fallback:  # the posterior's own extreme draw can put the wall on the start (measured: x <= 0.41 on HC)
        where = {k: float(icc.conservative_location[k][0]) for k in fallback}
        raise ValueError(f"inferred_run: the conservative boundary of {', '.join(fallback)} would come from "
                         f"{next(iter(fallback.values()))}, not from the good demonstrations (boundary {where}); "
                         f"run pbicrl infer again where its dataset can be read, or choose another cost_mode")
    ident = {"summary_sha256": _file_sha256(summary), "mode": mode,
             "used": [icc.feature_names[j] for j in icc.used],
             "boundary": {k: [float(v) for v in np.ravel(b)] for k, b in icc.conservative_location.items()},
             "p_constraint": {icc.feature_names[j]: float(icc.p_constraint[j]) for j in icc.used}}
    return icc, ident


def _file_sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class RunBusyError(RuntimeError):
    """Another live process holds the run directory's lock (it is training that run)."""


def _acquire(lock: Path) -> None:
    """Create ``lock`` holding this process id; refuse while another live process holds it."""
    from pbicrl._atomic import pid_alive

    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                pid = int(lock.read_text().strip() or "0")
            except (OSError, ValueError):
                pid = 0
            if pid and pid != os.getpid() and pid_alive(pid):
                raise RunBusyError(f"out: {lock.parent} is being trained by process {pid}; wait for it or stop it")
            lock.unlink(missing_ok=True)  # stale: its process is gone
            continue
        with os.fdopen(fd, "w") as fh:
            fh.write(str(os.getpid()))
        return
    raise RuntimeError(f"out: could not take the lock {lock}")


class CheckpointPolicy:
    """The policy of a checkpoint of :func:`train_policy` (``checkpoint.pt`` or ``best.pt``), without its
    environments: ``policy(obs) -> action`` (the Gaussian's mean, or a draw when ``deterministic=False``).

    Parameters
    ----------
    path : path
        The checkpoint (read with ``torch.load(weights_only=True)``).
    deterministic : bool
        Act with the mean (default, as the benchmark generates its demonstrations) or draw from the policy.
    seed : int
        Seed of the action noise (``deterministic=False``).
    """

    def __init__(self, path: str | os.PathLike[str], *, deterministic: bool = True, seed: int = 0) -> None:
        import torch

        from pbicrl.baselines.ppo_lagrangian import ActorCritic

        st = load_run_checkpoint(Path(path))["agent"]
        cfg = st["config"]
        pi_w = st["ac"]["pi.0.weight"]
        self.obs_dim = int(pi_w.shape[1])
        self.act_dim = int(st["ac"]["log_std"].shape[0])
        self.ac = ActorCritic(self.obs_dim, self.act_dim, tuple(cfg["hidden"]), float(cfg["init_log_std"]))
        self.ac.load_state_dict(st["ac"])
        self.ac.eval()
        self.normalize = bool(cfg.get("normalize_obs", True))
        self.mean = st["obs_rms"]["mean"].numpy().astype(np.float64)
        self.std = np.sqrt(st["obs_rms"]["var"].numpy().astype(np.float64) + 1e-8)
        self.deterministic = bool(deterministic)
        self._gen = torch.Generator().manual_seed(int(seed))
        self.steps = int(st["num_steps"])

    def reset(self, seed: int) -> None:
        """Re-seed the action noise (:func:`rollout_episodes` calls it with each episode's reset seed, so that
        an episode of a stochastic policy does not depend on the episodes before it)."""
        self._gen.manual_seed(int(seed))

    def __call__(self, obs: Any) -> NDArray[np.float64]:
        import torch

        o = np.asarray(obs, dtype=np.float64).reshape(-1)
        if o.shape != (self.obs_dim,):
            raise ValueError(f"obs: expected shape ({self.obs_dim},), got {np.shape(obs)}")
        x = np.clip((o - self.mean) / self.std, -10.0, 10.0) if self.normalize else o
        with torch.no_grad():
            d = self.ac.dist(torch.as_tensor(x[None], dtype=torch.float32))
            a = d.mean if self.deterministic else d.mean + d.stddev * torch.randn(d.mean.shape, generator=self._gen)
        return a.numpy()[0].astype(np.float64)  # the environment clips to its action box


def rollout_episodes(task: str, policy: Callable[[Any], Any], episodes: int, *, seed: int = 0) -> list[dict[str, Any]]:
    """Run ``episodes`` episodes of ``policy`` on ``task`` (reset seeds ``seed, seed + 1, ...``) and record them.

    A policy with a ``reset(seed)`` method is reset with each episode's reset seed before its first action.

    Returns
    -------
    list of dict
        Per episode: ``features`` (T, d) (``info["features"]``, the reward's terms), ``x`` (T,) the post-step
        ``obs[0]`` (the state the wall constrains), ``actions`` (T, a) clipped to the action box, ``obs`` (T+1, n)
        raw observations from the reset on, ``rewards`` and ``costs`` (T,), ``seed``, and the benchmark's metrics
        (:func:`episode_metrics`).
    """
    if int(episodes) < 1:
        raise ValueError(f"episodes: must be >= 1, got {episodes!r}")
    env = make_task_env(task)
    low, high = env.action_space.low, env.action_space.high
    out = []
    try:
        for k in range(int(episodes)):
            obs, _ = env.reset(seed=int(seed) + k)
            if callable(getattr(policy, "reset", None)):
                policy.reset(int(seed) + k)  # type: ignore[attr-defined]
            obs_l, feats, xs, acts, rews, costs = [np.asarray(obs, dtype=np.float64)], [], [], [], [], []
            while True:
                a = np.clip(np.asarray(policy(obs), dtype=np.float64), low, high)
                obs, r, term, trunc, info = env.step(a)
                obs_l.append(np.asarray(obs, dtype=np.float64))
                feats.append(np.asarray(info["features"], dtype=np.float64))
                xs.append(float(np.asarray(obs).reshape(-1)[0]))
                acts.append(a)
                rews.append(float(r))
                costs.append(float(info["cost"]))
                if term or trunc:
                    break
            out.append({"features": np.stack(feats), "x": np.asarray(xs), "actions": np.stack(acts),
                        "obs": np.stack(obs_l), "rewards": np.asarray(rews), "costs": np.asarray(costs),
                        "seed": int(seed) + k, **episode_metrics(rews, costs)})
    finally:
        env.close()
    return out


def demonstrations_dataset(task: str, groups: dict[int, Sequence[dict[str, Any]]]) -> Any:
    """A :class:`pbicrl.inference.data.Dataset` of recorded episodes (:func:`rollout_episodes`) in ranked groups.

    ``groups[k]`` are the episodes of group ``k`` (1 = best). Features: the task's nominal features (the reward's
    terms, with ``nominal_weights``); states: the post-step x (one column), which a parametric wall constraint
    (``axis_halfspace`` on column 0) indexes; actions (none when an episode has no ``actions``); ``env_id`` the
    task's Gymnasium id.
    """
    from pbicrl.envs.icrl_benchmark import icrl_task
    from pbicrl.inference.data import Dataset

    spec = icrl_task(task)
    feats, states, acts, labels, offsets = [], [], [], [], [0]
    for g in sorted(groups):
        if int(g) != g or g < 1:
            raise ValueError(f"groups: labels must be integers >= 1, got {g!r}")
        for ep in groups[g]:
            feats.append(np.asarray(ep["features"], dtype=np.float64))
            states.append(np.asarray(ep["x"], dtype=np.float64)[:, None])
            if "actions" in ep:
                acts.append(np.asarray(ep["actions"], dtype=np.float64))
            labels.append(int(g))
            offsets.append(offsets[-1] + len(ep["x"]))
    if len(set(labels)) < 2:
        raise ValueError(f"groups: need episodes in at least two groups, got labels {sorted(set(labels))}")
    return Dataset(features=np.concatenate(feats), offsets=np.asarray(offsets), group=np.asarray(labels),
                   states=np.concatenate(states), actions=np.concatenate(acts) if len(acts) == len(labels) else None,
                   feature_names=spec.feature_names, nominal_weights=np.asarray(spec.nominal_weights),
                   env_id=spec.env_id)
