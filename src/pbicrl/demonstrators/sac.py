"""Resumable Soft Actor-Critic training (Stable-Baselines3) for demonstrators.

:func:`train_sac` trains an SB3 SAC agent on any Gymnasium environment and is
built to survive interruptions on a shared CPU box:

* every ``checkpoint_every`` steps it writes ``out_dir/checkpoint/`` (full model
  with optimisers, replay buffer as ``replay_buffer.npz``, step count, cumulative wall time) atomically;
  calling :func:`train_sac` again with the same ``out_dir`` resumes from it;
* SIGTERM/SIGINT stop training cleanly after writing a checkpoint;
* ``out_dir/progress.log`` gets one line per ``log_every`` steps (steps, steps/s,
  mean return and length of the recent episodes);
* ``out_dir/budget.json`` records requested/done steps, wall time, all
  hyperparameters and library versions;
* at the end ``out_dir/policy.zip`` holds only the policy networks (small, no
  replay buffer or optimiser state; load with :func:`load_policy`) and
  ``out_dir/final_model.zip`` the full model (for warm starts via ``init_from``).

Every file is written and read in pbicrl's own format (:mod:`pbicrl.demonstrators.sac_files`: settings as
JSON checked against a schema, tensors read with ``torch.load(weights_only=True)``, replay buffers as plain
``.npz``), never with pickle, so a policy or checkpoint from someone else cannot run code when opened.

Defaults follow the paper's SAC table (learning rate 3e-4 for all nets, batch 128,
two hidden layers of 256 units, replay buffer 10 000).

Torch and Stable-Baselines3 are imported lazily; without them an ImportError
names ``pip install "pbicrl[rl]"``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from pbicrl._atomic import atomic_dir, clean_stale_temporaries, write_text
from pbicrl.baselines.session import StopSignals, library_versions, progress_logger

__all__ = ["SACConfig", "load_policy", "require_rl", "train_sac"]

_CKPT = "checkpoint"
_CKPT_OLD = "checkpoint.old"
#: Libraries whose versions ``budget.json`` records (one that is missing is noted as unknown).
_VERSIONED = ("numpy", "torch", "stable_baselines3", "gymnasium", "mujoco")


def require_rl() -> tuple[Any, Any]:
    """Import torch and stable_baselines3 or raise an ImportError naming the extra."""
    try:
        import stable_baselines3
        import torch
    except ImportError as exc:
        raise ImportError(
            f"SAC training needs torch and stable-baselines3 ({exc}): pip install \"pbicrl[rl]\""
        ) from exc
    return torch, stable_baselines3


class SACConfig(dict):
    """Plain dict of the hyperparameters recorded in ``budget.json``."""


def _is_finite(value: Any) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


def _write_json_atomic(path: Path, obj: Any) -> None:
    write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def _is_policy_only(path: Path) -> bool:
    """True for a policy file (``policy.zip``), False for a whole model (``final_model.zip``)."""
    from pbicrl.demonstrators.sac_files import MODEL_FORMAT, file_format

    return file_format(path) != MODEL_FORMAT


def _read_state(path: Path) -> dict:
    """A checkpoint's ``state.json``, checked: an object with a number of steps, a wall time and a session list."""
    from pbicrl.demonstrators import sac_files

    try:
        state = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise sac_files.SACFileError(f"checkpoint: {path} is not readable JSON ({exc})") from None
    if not isinstance(state, dict):
        raise sac_files.SACFileError(f"checkpoint: {path} must hold a JSON object, got {type(state).__name__}")
    for key, kinds in (("num_timesteps", (int,)), ("wall_time_s", (int, float)), ("sessions", (list,))):
        if key in state and (not isinstance(state[key], kinds) or isinstance(state[key], bool)):
            raise sac_files.SACFileError(f"checkpoint: {path}: field '{key}' must be "
                                         f"{'a list' if key == 'sessions' else 'a number'}, got {state[key]!r}")
    if not math.isfinite(float(state.get("wall_time_s", 0.0))):
        raise sac_files.SACFileError(f"checkpoint: {path}: field 'wall_time_s' must be finite")
    return state


def _find_checkpoint(out_dir: Path) -> Path | None:
    clean_stale_temporaries(out_dir / _CKPT)  # a swap killed half-way: put the previous checkpoint back
    for name in (_CKPT, _CKPT_OLD):  # checkpoint.old: the swap of earlier versions, killed half-way
        d = out_dir / name
        if (d / "state.json").is_file() and (d / "model.zip").is_file():
            if (d / "replay_buffer.npz").is_file():
                return d
            if (d / "replay_buffer.pkl").is_file():  # an earlier pbicrl's pickles: refuse, never start afresh over it
                raise ValueError(f"out_dir: {d} is a checkpoint in the pickle format of earlier versions, which "
                                 "pbicrl no longer reads (opening it could run code stored in it); convert a run "
                                 "you trust with pbicrl.demonstrators.sac_files.convert_sb3_checkpoint("
                                 f"{str(out_dir)!r}), or choose another out_dir")
            # a model without its replay buffer: training afresh would replace it at the first save
            raise ValueError(f"out_dir: {d} holds a checkpoint without its replay buffer (replay_buffer.npz), so "
                             "it cannot be resumed; pbicrl does not start afresh over it (the first save would "
                             "replace the model). Move it away to keep it, or choose another out_dir")
    return None


def _save_checkpoint(model: Any, out_dir: Path, state: dict[str, Any]) -> None:
    """Write model + replay buffer + state into a temp dir, then swap it in."""
    from pbicrl.demonstrators import sac_files

    with atomic_dir(out_dir / _CKPT, replace=True) as tmp:
        sac_files.save_model(model, tmp / "model.zip")
        sac_files.save_replay_buffer(model, tmp / "replay_buffer.npz")
        _write_json_atomic(tmp / "state.json", state)
    old = out_dir / _CKPT_OLD
    if old.exists():  # left by an earlier version's swap; the new checkpoint is complete
        shutil.rmtree(old)


def load_policy(path: str | os.PathLike, device: str = "cpu") -> Any:
    """Load a ``policy.zip`` written by :func:`train_sac`, or the policy of a whole ``model.zip`` (a
    checkpoint, e.g. ``training/<run>/model.zip``).

    Raises
    ------
    FileNotFoundError
        No such file.
    pbicrl.demonstrators.sac_files.SACFileError
        A Stable-Baselines3 pickle (refused: opening it could run code) or an invalid file; a ``ValueError``.

    Returns
    -------
    stable_baselines3.sac.policies.SACPolicy
        Call ``policy.predict(obs, deterministic=...)`` to act.
    """
    require_rl()
    from pbicrl.demonstrators.sac_files import read_policy

    # a whole model (networks, optimisers, hyperparameters): its policy is all we act with
    return read_policy(path, device=device)


def _prefill_replay_buffer(model: Any, env_fn: Callable[[], Any], n_steps: int, seed: int) -> int:
    """Add ``n_steps`` transitions of ``model``'s own policy (sampled actions) to its replay buffer.

    Returns the number of episodes that ended. Runs in a separate environment so that the
    training env's episode statistics start clean.
    """
    import numpy as np

    env = env_fn()
    try:
        obs, _ = env.reset(seed=seed)
        ended = 0
        for _ in range(n_steps):
            action, _ = model.predict(obs, deterministic=False)
            next_obs, reward, terminated, truncated, _ = env.step(action)
            done = bool(terminated or truncated)
            # SB3 stores actions scaled to [-1, 1] and bootstraps through time-limit truncations
            model.replay_buffer.add(np.asarray(obs)[None], np.asarray(next_obs)[None],
                                    np.asarray(model.policy.scale_action(action))[None],
                                    np.array([reward], dtype=np.float32), np.array([done]),
                                    [{"TimeLimit.truncated": bool(truncated and not terminated)}])
            obs = next_obs
            if done:
                ended += 1
                obs, _ = env.reset()
    finally:
        env.close()
    return ended


def train_sac(
    env_fn: Callable[[], Any],
    total_steps: int,
    out_dir: str | os.PathLike,
    *,
    seed: int = 0,
    learning_rate: float = 3e-4,
    batch_size: int = 128,
    net_arch: Sequence[int] = (256, 256),
    buffer_size: int = 10_000,
    learning_starts: int = 10_000,
    gamma: float = 0.99,
    tau: float = 0.005,
    train_freq: int = 1,
    gradient_steps: int = 1,
    checkpoint_every: int = 10_000,
    log_every: int = 2_000,
    torch_threads: int = 1,
    init_from: str | os.PathLike | None = None,
    metadata: dict[str, Any] | None = None,
    progress: bool = True,
    policy_kwargs: dict[str, Any] | None = None,
    ent_coef: float | str = "auto",
    replay_buffer_kwargs: dict[str, Any] | None = None,
    deadline: float | None = None,
    prefill_steps: int = 0,
    target_entropy: float | str = "auto",
) -> Path:
    """Train (or resume training of) a SAC agent; return the path of ``policy.zip``.

    Parameters
    ----------
    env_fn : callable
        Zero-argument factory returning a fresh Gymnasium environment (time limit included).
    total_steps : int
        Total environment steps to reach, counted across resumes.
    out_dir : path
        Run directory (created). If it holds a checkpoint, training resumes from it.
    seed : int
        Seed for SB3/torch and the environment resets (offset by the resume count).
    learning_rate, batch_size, net_arch, buffer_size, gamma, tau, train_freq, gradient_steps
        SAC hyperparameters (same learning rate for actor, critics and temperature).
    learning_starts : int
        Number of initial steps with uniformly random actions (the paper used 40 episodes).
    checkpoint_every : int
        Steps between checkpoints (model + replay buffer).
    log_every : int
        Steps between lines in ``progress.log``.
    torch_threads : int
        ``torch.set_num_threads`` value (1 is fastest for these small networks on a shared CPU).
    init_from : path, optional
        SB3 model zip (e.g. another run's ``final_model.zip``) or a policy-only ``policy.zip``
        (e.g. a shipped demonstrator) whose networks initialise a fresh run (warm start; no
        replay buffer or optimiser state is used). Ignored when resuming.
    metadata : dict, optional
        JSON-serialisable description (environment, reward) stored in ``budget.json``.
    progress : bool
        Also echo the progress lines to stderr.
    policy_kwargs : dict, optional
        Extra SB3 ``policy_kwargs`` for a new run (e.g. a ``features_extractor_class`` that
        rescales observations); ``net_arch`` always comes from ``net_arch``.
    ent_coef : float or str
        SAC entropy coefficient: ``"auto"`` (learned, SB3 default; ``"auto_0.1"`` sets its
        initial value) or a fixed float.
    replay_buffer_kwargs : dict, optional
        Passed to SB3's replay buffer of a new run (e.g. ``{"handle_timeout_termination": False}``
        to treat time-limit truncations as terminal).
    deadline : float, optional
        Unix time (``time.time()``) at which to stop early and finalise the policy with
        the steps done so far (``budget.json`` status ``"deadline"``): a wall-clock budget
        for shared machines. A later call (larger ``total_steps`` or later deadline) resumes.
    prefill_steps : int
        Warm starts only (``init_from``): before the first gradient step, fill the fresh replay
        buffer with this many transitions of the loaded policy itself (sampled actions). A warm
        start whose buffer holds only ``learning_starts`` uniformly random steps trains its
        critics on a few thousand transitions and loses most of what the policy could do;
        with the policy's own experience it starts from a buffer like the one it left.
        Not counted in ``total_steps``; ignored when resuming (the buffer is restored).
    target_entropy : float or "auto"
        Entropy the automatic temperature steers the policy towards (``"auto"``: SB3's
        ``-dim(action)``). Lower values give a less noisy sampled policy. Applies to new runs and
        warm starts; a resumed checkpoint keeps its own.

    Returns
    -------
    pathlib.Path
        ``out_dir/policy.zip`` if training completed; if it was interrupted by a signal,
        the checkpoint was written and ``KeyboardInterrupt`` is raised instead.

    Raises
    ------
    ValueError
        For invalid option values (the message names the option).
    """
    torch, _sb3 = require_rl()
    from stable_baselines3 import SAC

    from pbicrl.demonstrators import sac_files
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.monitor import Monitor

    for name, value, lo in (("total_steps", total_steps, 1), ("batch_size", batch_size, 1),
                            ("buffer_size", buffer_size, 1), ("learning_starts", learning_starts, 0),
                            ("checkpoint_every", checkpoint_every, 1), ("log_every", log_every, 1),
                            ("torch_threads", torch_threads, 1), ("train_freq", train_freq, 1),
                            ("gradient_steps", gradient_steps, 1), ("prefill_steps", prefill_steps, 0)):
        if int(value) != value or int(value) < lo:
            raise ValueError(f"{name}: must be an integer >= {lo}, got {value!r}")
    if deadline is not None and not _is_finite(deadline):
        raise ValueError(f"deadline: must be a finite unix time, got {deadline!r}")
    if not (learning_rate > 0):
        raise ValueError(f"learning_rate: must be > 0, got {learning_rate!r}")
    if target_entropy != "auto" and not _is_finite(target_entropy):
        raise ValueError(f"target_entropy: must be 'auto' or a finite number, got {target_entropy!r}")
    if prefill_steps and init_from is None:
        raise ValueError("prefill_steps: needs init_from (a new run starts with learning_starts random steps)")
    if prefill_steps > buffer_size:
        raise ValueError(f"prefill_steps: must be <= buffer_size ({buffer_size}), got {prefill_steps}")
    net_arch = [int(h) for h in net_arch]
    if not net_arch or min(net_arch) < 1:
        raise ValueError(f"net_arch: must be a non-empty list of positive layer sizes, got {net_arch!r}")

    torch.set_num_threads(int(torch_threads))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    log_path = out_dir / "progress.log"
    budget_path = out_dir / "budget.json"

    hyper = SACConfig(learning_rate=learning_rate, batch_size=batch_size, net_arch=net_arch,
                      buffer_size=buffer_size, learning_starts=learning_starts, gamma=gamma, tau=tau,
                      train_freq=train_freq, gradient_steps=gradient_steps, seed=seed,
                      torch_threads=torch_threads, ent_coef=ent_coef, replay_buffer_kwargs=replay_buffer_kwargs,
                      init_from=None if init_from is None else str(init_from), prefill_steps=int(prefill_steps),
                      policy_kwargs=None if not policy_kwargs else {k: repr(v) for k, v in policy_kwargs.items()})

    log = progress_logger(log_path, echo=progress)

    env = Monitor(env_fn())
    ckpt = _find_checkpoint(out_dir)
    if ckpt is not None:
        state = _read_state(ckpt / "state.json")
        model = sac_files.read_model(ckpt / "model.zip", env, what="checkpoint")
        sac_files.read_replay_buffer(model, ckpt / "replay_buffer.npz")
        sessions = list(state.get("sessions", []))
        wall_before = float(state.get("wall_time_s", 0.0))
        log(f"resume from {ckpt.name} at step {model.num_timesteps} (session {len(sessions) + 1})")
    else:
        state = {}
        sessions = []
        wall_before = 0.0
        if init_from is not None:
            init_path = Path(init_from)
            if not init_path.is_file():
                raise ValueError(f"init_from: no such model file {init_path}")
            custom = {"learning_rate": learning_rate, "batch_size": batch_size, "buffer_size": buffer_size,
                      "learning_starts": learning_starts, "gamma": gamma, "tau": tau,
                      "train_freq": train_freq, "gradient_steps": gradient_steps}
            if target_entropy != "auto":
                custom["target_entropy"] = float(target_entropy)
            if _is_policy_only(init_path):
                # a shipped ``policy.zip`` (networks only): fresh SAC, then copy actor and critics in
                model = SAC("MlpPolicy", env, learning_rate=learning_rate, buffer_size=buffer_size,
                            ent_coef=ent_coef, replay_buffer_kwargs=replay_buffer_kwargs,
                            target_entropy=target_entropy, learning_starts=learning_starts,
                            batch_size=batch_size, tau=tau, gamma=gamma,
                            train_freq=train_freq, gradient_steps=gradient_steps,
                            policy_kwargs={**(policy_kwargs or {}), "net_arch": net_arch}, seed=seed,
                            device="cpu", verbose=0)
                src = sac_files.read_policy(init_path, what="init_from")
                try:
                    model.policy.load_state_dict(src.state_dict())
                except RuntimeError as exc:
                    raise ValueError(f"init_from: {init_path} does not fit this environment/net_arch ({exc})") from None
            else:
                model = sac_files.read_model(init_path, env, what="init_from", overrides=custom)
            model.num_timesteps = 0
            model._episode_num = 0
            model.ep_info_buffer = None  # report only this run's episodes
            model.ep_success_buffer = None
            log(f"new run warm-started from {init_path}")
            if prefill_steps:
                t0 = time.time()
                ended = _prefill_replay_buffer(model, env_fn, int(prefill_steps), seed + 500)
                log(f"replay buffer prefilled with {prefill_steps} steps of the loaded policy "
                    f"({ended} episodes ended, {time.time() - t0:.0f} s)")
        else:
            model = SAC("MlpPolicy", env, learning_rate=learning_rate, buffer_size=buffer_size, ent_coef=ent_coef,
                        replay_buffer_kwargs=replay_buffer_kwargs, target_entropy=target_entropy,
                        learning_starts=learning_starts, batch_size=batch_size, tau=tau, gamma=gamma,
                        train_freq=train_freq, gradient_steps=gradient_steps,
                        policy_kwargs={**(policy_kwargs or {}), "net_arch": net_arch}, seed=seed,
                        device="cpu", verbose=0)
            log("new run")
    # record what the model actually uses: a resumed (or externally prepared) checkpoint keeps
    # its own settings, whatever was passed to this call
    hyper.update(tau=float(model.tau), gamma=float(model.gamma), batch_size=int(model.batch_size),
                 buffer_size=int(model.buffer_size), learning_starts=int(model.learning_starts),
                 ent_coef=model.ent_coef if isinstance(model.ent_coef, str) else float(model.ent_coef),
                 target_entropy=float(model.target_entropy))
    session_idx = len(sessions)
    model.set_random_seed(seed + 1000 * session_idx)
    env.reset(seed=seed + 1000 * session_idx)

    start_steps = int(model.num_timesteps)
    t_start = time.time()
    stop = {"deadline": False}
    signals = StopSignals().install()  # SIGTERM/SIGINT: stop at the next step; the checkpoint is written below

    def make_state(done: int) -> dict[str, Any]:
        return {"num_timesteps": done, "wall_time_s": wall_before + (time.time() - t_start),
                "sessions": sessions + [{"start_step": start_steps, "end_step": done,
                                         "wall_time_s": time.time() - t_start,
                                         "started_utc": time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(t_start))}]}

    def write_budget(done: int, status: str) -> None:
        st = make_state(done)
        _write_json_atomic(budget_path, {
            "requested_steps": int(total_steps), "done_steps": done, "status": status,
            "wall_time_s": round(st["wall_time_s"], 1), "sessions": st["sessions"],
            "mean_steps_per_s": round(done / st["wall_time_s"], 2) if st["wall_time_s"] > 0 else None,
            "hyperparameters": dict(hyper), "versions": library_versions(_VERSIONED, note_failures=True),
            "metadata": metadata or {},
        })

    class _Cb(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self._last_t = time.time()
            self._last_n = start_steps

        def _on_step(self) -> bool:
            n = self.model.num_timesteps
            if n % log_every == 0:
                now = time.time()
                rate = (n - self._last_n) / max(now - self._last_t, 1e-9)
                self._last_t, self._last_n = now, n
                eps = list(self.model.ep_info_buffer)[-10:]
                ret = sum(e["r"] for e in eps) / len(eps) if eps else float("nan")
                ln = sum(e["l"] for e in eps) / len(eps) if eps else float("nan")
                log(f"steps {n}/{total_steps} rate {rate:.1f}/s ep_return(last{len(eps)}) {ret:.2f} "
                    f"ep_len {ln:.0f}")
            if n % checkpoint_every == 0 and n < total_steps:
                _save_checkpoint(self.model, out_dir, make_state(n))
                write_budget(n, "running")
            if deadline is not None and time.time() >= deadline:
                stop["deadline"] = True
            return not (signals.requested or stop["deadline"])

    remaining = int(total_steps) - start_steps
    try:
        if deadline is not None and time.time() >= deadline:
            stop["deadline"] = True
        elif remaining > 0:
            write_budget(start_steps, "running")
            model.learn(total_timesteps=remaining, callback=_Cb(), reset_num_timesteps=False,
                        log_interval=10**9, progress_bar=False)
    finally:
        signals.restore()
    done = int(model.num_timesteps)
    if done < total_steps and (signals.requested or not stop["deadline"]):
        _save_checkpoint(model, out_dir, make_state(done))
        write_budget(done, "interrupted")
        log(f"interrupted at step {done}; checkpoint written")
        env.close()
        raise KeyboardInterrupt(f"SAC training interrupted at step {done}/{total_steps}; rerun to resume")

    sac_files.save_model(model, out_dir / "final_model.zip")
    sac_files.save_policy(model.policy, out_dir / "policy.zip")
    status = "complete" if done >= total_steps else "deadline"
    write_budget(done, status)
    if status == "deadline":
        log(f"deadline reached at step {done}/{total_steps}; policy finalised with the steps done")
    # keep the last checkpoint only if the caller may want to extend training
    _save_checkpoint(model, out_dir, make_state(done))
    log(f"done: {done} steps, policy at {out_dir / 'policy.zip'}")
    env.close()
    return out_dir / "policy.zip"
