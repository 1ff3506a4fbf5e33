"""One ICL run (:func:`run_icl`): alternate constrained RL and constraint adjustment for ``rounds`` rounds,
resumable from its checkpoint."""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

try:
    import torch
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError('pbicrl.baselines.icl needs PyTorch: pip install "pbicrl[rl]"') from exc

from pbicrl._atomic import atomic_path
from pbicrl.baselines.icl.checkpoint import CHECKPOINT, load_checkpoint, save_checkpoint, write_json_file
from pbicrl.baselines.icl.environments import ICLEnv, icl_env
from pbicrl.baselines.icl.losses import accrual, constraint_location, constraint_loss, discount_matrix, mixture_weights
from pbicrl.baselines.icl.network import ConstraintNet
from pbicrl.baselines.icl.presets import ICLConfig, icl_preset
from pbicrl.baselines.ppo_lagrangian import PPOLagrangian
from pbicrl.baselines.session import SessionClock, StopSignals, library_versions, progress_logger

__all__ = ["run_icl"]


def _rollout_coords(ppo: PPOLagrangian, env: Any, coord: Callable, n: int, seed: int,
                    deterministic: bool = False) -> tuple[list[NDArray], list[float]]:
    """Sample ``n`` episodes of the current policy; their coordinates after each step and returns."""
    trajs, rets = [], []
    g = torch.Generator().manual_seed(seed)
    for e in range(n):
        obs, _ = env.reset(seed=seed + e)
        cs, ret = [], 0.0
        while True:
            x = torch.as_tensor(ppo._norm(np.asarray(obs, dtype=np.float64).reshape(1, -1)), dtype=torch.float32)
            with torch.no_grad():
                d = ppo.ac.dist(x)
                a = d.mean if deterministic else d.mean + d.stddev * torch.randn(d.mean.shape, generator=g)
            a = np.clip(a.numpy()[0].astype(np.float64), ppo.act_low, ppo.act_high)
            obs, r, term, trunc, info = env.step(a)
            cs.append(np.asarray(coord(obs, info), dtype=np.float64).reshape(-1))
            ret += float(r)
            if term or trunc:
                break
        trajs.append(np.asarray(cs))
        rets.append(ret)
    return trajs, rets


def _location(net: ConstraintNet, spec: ICLEnv, xmin: float, xmax: float | None = None) -> float | None:
    """Constraint location: downward for a wall behind (``spec.side == "behind"``) from the lowest expert
    coordinate ``xmin`` (the demonstrations' nearest approach to it, beyond which they say nothing); upward for a
    wall in front from ``xmin`` (``spec.scan_from == "lowest"``: the demonstrations' start; the network's
    extrapolation below any data says nothing about a halfspace ``x >= theta``) or from the highest expert
    coordinate ``xmax`` (``"nearest"``: their nearest approach, for demonstrations that roam on both sides of
    the start)."""
    if spec.location_grid is None:
        return None
    if spec.side != "behind" and spec.scan_from == "nearest":
        if xmax is None:
            raise ValueError("xmax: a wall in front scanned from the nearest approach needs the highest expert x")
        xmin = xmax
    if spec.side == "behind":
        g = np.concatenate([[xmin], spec.location_grid[spec.location_grid < xmin][::-1]])
        if g.size < 2:
            return None
        # constraint_location scans an increasing grid: scan the mirrored one
        loc = constraint_location(net.numpy(g), -g)
        return None if loc is None else -loc
    g = spec.location_grid[spec.location_grid > xmin]
    g = np.concatenate([[xmin], g])
    return constraint_location(net.numpy(g), g)


def run_icl(env: str | ICLEnv, expert: Sequence[NDArray], config: ICLConfig | str = "default", out_dir: str | os.PathLike = "icl-run",
            *, seed: int = 0, progress: bool = True, max_session_steps: int | None = None,
            on_update: Callable[[PPOLagrangian, dict], bool | None] | None = None) -> dict[str, Any]:
    """Run (or resume) ICL and return its summary (also written to ``out_dir/summary.json``).

    Parameters
    ----------
    env : str or ICLEnv
        ``"halfcheetah"``, ``"ant"``, ``"point_mass"`` or a custom :class:`ICLEnv`.
    expert : sequence of ndarray, each (T_i, k)
        Constrained coordinates of the expert trajectories (:func:`expert_coordinates`).
    config : ICLConfig or preset name
    out_dir : path
        Run directory: ``checkpoint.pt`` (resume point), ``progress.log``, ``budget.json``, and at the end
        ``constraint.pt``, ``constraint_grid.npz`` and ``summary.json``.
    seed : int
    progress : bool
        Echo the log lines to stderr.
    max_session_steps : int, optional
        Stop after this many PPO steps in this call (checkpoint, then ``KeyboardInterrupt``), e.g. to run a
        long budget in slices on a shared machine; calling again resumes.
    on_update : callable, optional
        ``on_update(ppo, info)`` after every PPO update (before the checkpoint that update may trigger), e.g. to
        log the training episodes; returning ``False`` stops the run as SIGTERM does (checkpoint, then
        ``KeyboardInterrupt``); any other return value (None included) lets it go on.

    Returns
    -------
    dict
        ``location`` (1-D coordinates: where c first reaches 0.5 scanning from the lowest expert coordinate, up for
        a wall in front and down for one behind (:attr:`ICLEnv.side`); None if it never does), ``cmse_location`` (None
        without a location), ``cmse_grid``, ``runtime_s`` (wall time summed over sessions), per-round history,
        final-policy statistics and the budget.
    """
    from pbicrl.analysis.metrics import cmse_grid, cmse_location

    spec = icl_env(env) if isinstance(env, str) else env
    cfg = icl_preset(config, spec.name) if isinstance(config, str) else config.validate()
    from pbicrl.envs._mujoco_compat import quiet_mujoco_warnings

    quiet_mujoco_warnings()  # no MUJOCO_LOG.TXT in the working directory, no deprecation note per environment
    if len(expert) == 0:
        raise ValueError("expert: need at least one expert trajectory")
    expert = [np.asarray(t, dtype=np.float64).reshape(len(t), -1) for t in expert]
    k = expert[0].shape[1]
    if any(t.shape[1] != k for t in expert) or any(len(t) == 0 for t in expert):
        raise ValueError("expert: trajectories must be non-empty with the same number of coordinates")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    log_path = out / "progress.log"
    torch.set_num_threads(int(cfg.ppo.torch_threads))
    torch.manual_seed(seed)

    log = progress_logger(log_path, echo=progress)

    allc = np.concatenate(expert)
    h = hashlib.sha256(np.asarray([len(t) for t in expert], dtype=np.int64).tobytes())
    h.update(np.ascontiguousarray(allc).tobytes())
    fingerprint = h.hexdigest()
    xmin, xmax = float(allc[:, 0].min()), float(allc[:, 0].max())
    center, scale = allc.mean(0), allc.std(0) + 1e-3
    net = ConstraintNet(k, cfg.constraint_hidden, center, scale, cfg.init_bias)
    copt = torch.optim.Adam(net.parameters(), lr=cfg.constraint_lr)

    def cost_np(c: NDArray) -> NDArray:
        return net.numpy(c)

    ppo = PPOLagrangian(spec.make, spec.coord, cost_np, cfg.ppo, seed=seed)
    eval_env = (spec.make_eval or spec.make)()
    # accrual bins: the expert's range widened on both sides (policies may roam far beyond it); the floor keeps
    # a degenerate range usable without coarsening small-scale tasks (the pendulum's cart moves ~0.1)
    lo, hi = allc.min(0), allc.max(0)
    span = np.maximum(hi - lo, 1e-3)
    edges = [np.linspace(lo[d] - 2 * span[d], hi[d] + 2 * span[d], cfg.accrual_bins + 1) for d in range(k)]
    exp_acc = accrual(expert, cfg.gamma, edges)
    exp_mat = discount_matrix(expert, cfg.gamma)

    state: dict[str, Any] = {"round": 0, "phase": "rl", "snapshots": [], "history": [], "wall_time_s": 0.0,
                             "sessions": []}
    ckpt = out / CHECKPOINT
    if ckpt.is_file():
        st = load_checkpoint(ckpt)
        if st.get("config") != cfg.to_dict() or st.get("seed") != seed:
            raise ValueError(f"out_dir: {out} holds a checkpoint of a different ICL configuration or seed; "
                             "use another directory")
        if st.get("expert_sha256") != fingerprint:
            raise ValueError(f"out_dir: {out} holds a checkpoint made with different expert data; "
                             "use another directory")
        ppo.load_state_dict(st["ppo"])
        net.load_state_dict(st["constraint"])
        copt.load_state_dict(st["constraint_opt"])
        state = st["state"]
        if state["round"] >= cfg.rounds and (out / "summary.json").is_file():
            ppo.close()
            eval_env.close()
            return json.loads((out / "summary.json").read_text())  # finished earlier: nothing to do
        log(f"resume: round {state['round'] + 1}/{cfg.rounds}, phase {state['phase']}, {ppo.num_steps} PPO steps")
    else:
        log(f"new ICL run: env {spec.name}, {len(expert)} expert trajectories, seed {seed}, "
            f"{cfg.rounds} rounds, {cfg.total_steps} PPO steps")
    t_session = time.time()
    wall_before = float(state["wall_time_s"])

    def save(status: str) -> None:
        now = time.time()
        st = dict(state)
        st["wall_time_s"] = wall_before + (now - t_session)
        st["sessions"] = state["sessions"] + [{"started_utc": time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(t_session)),
                                               "wall_time_s": now - t_session, "end_steps": ppo.num_steps}]
        save_checkpoint({"config": cfg.to_dict(), "seed": seed, "expert_sha256": fingerprint, "ppo": ppo.state_dict(), "constraint": net.state_dict(),
                     "constraint_opt": copt.state_dict(), "state": st}, ckpt)
        write_json_file(out / "budget.json", {
            "status": status, "env": spec.name, "seed": seed, "n_expert": len(expert),
            "requested_ppo_steps": cfg.total_steps, "done_ppo_steps": ppo.num_steps, "rounds": cfg.rounds,
            "rounds_done": state["round"], "wall_time_s": round(st["wall_time_s"], 1), "sessions": st["sessions"],
            "config": cfg.to_dict(), "versions": library_versions()})

    stop = StopSignals().install()  # SIGTERM/SIGINT: checkpoint, then stop

    clock = SessionClock(save, stop, ppo.num_steps, cfg.checkpoint_every, max_session_steps)
    last_log = {"t": time.time()}

    def on_ppo_update(p: PPOLagrangian, info: dict) -> bool:
        if on_update is not None and on_update(p, info) is False:
            stop.request()
        if time.time() - last_log["t"] > 30 or p.num_steps >= cfg.round_target(state["round"]):
            log(f"round {state['round'] + 1} steps {p.num_steps} return {info['ep_return']:.1f} len {info['ep_len']:.0f} "
                f"max_coord {info['ep_max_coord']:.2f} Jc {info['ep_cost']:.3f} lambda {info['lam_next']:.3f} "
                f"kl {info['approx_kl']:.4f} std {info['std']:.3f} ({cfg.ppo.n_envs * cfg.ppo.n_steps / info['seconds']:.0f} steps/s)")
            last_log["t"] = time.time()
        return clock.tick(p.num_steps)

    try:
        while state["round"] < cfg.rounds:
            r = state["round"]
            if state["phase"] == "rl":
                if cfg.reinit_policy and r > 0 and ppo.num_steps == cfg.round_target(r - 1):
                    fresh = PPOLagrangian(spec.make, spec.coord, cost_np, cfg.ppo, seed=seed + 1000 * r)
                    steps, nup = ppo.num_steps, ppo.num_updates
                    ppo.close()
                    ppo = fresh
                    ppo.num_steps, ppo.num_updates = steps, nup
                ppo.set_cost_fn(cost_np)
                ppo.learn(cfg.round_target(r), callback=on_ppo_update)
                if stop.requested:
                    save("interrupted")
                    log(f"interrupted at {ppo.num_steps} PPO steps; checkpoint written")
                    raise KeyboardInterrupt(f"ICL interrupted at {ppo.num_steps} steps; rerun to resume")
                trajs, rets = _rollout_coords(ppo, eval_env, spec.coord, cfg.policy_episodes,
                                              seed=seed * 1_000_003 + 101 * r)
                state["snapshots"].append({"trajs": [torch.as_tensor(t) for t in trajs], "returns": rets})
                state["phase"] = "constraint"
                save("running")
            # constraint adjustment over all policies so far
            snaps = [[t.numpy() for t in s["trajs"]] for s in state["snapshots"]]
            accs = [accrual(s, cfg.gamma, edges) for s in snaps]
            w = mixture_weights(accs, exp_acc, cfg.weighting)
            mats = [discount_matrix(s, cfg.gamma) for s in snaps]
            info0 = None
            for _ in range(cfg.constraint_steps):
                loss, info = constraint_loss(net, mats, w, exp_mat, cfg.beta, cfg.hinge_weight)
                info0 = info0 or info
                copt.zero_grad()
                loss.backward()
                copt.step()
            with torch.no_grad():
                loss, info = constraint_loss(net, mats, w, exp_mat, cfg.beta, cfg.hinge_weight)
            loc = _location(net, spec, xmin, xmax)
            grid_err = cmse_grid(spec.true_indicator(spec.grid), net.numpy(spec.grid))
            ret_mean = float(np.mean(state["snapshots"][-1]["returns"]))
            maxc = float(np.mean([t[:, 0].max() for t in snaps[-1]]))
            rec = {"round": r + 1, "ppo_steps": ppo.num_steps, "lambda": ppo.lam, "weights": w.tolist(),
                   "J_expert_before": info0["J_expert"], "J_expert": info["J_expert"], "J_agent": info["J_agent"],
                   "loss": float(loss), "location": loc, "cmse_grid": grid_err, "policy_return": ret_mean,
                   "policy_max_coord0": maxc}
            state["history"].append(rec)
            log(f"round {r + 1}/{cfg.rounds} constraint: J_expert {info['J_expert']:.3f} (beta {cfg.beta}), "
                f"J_agent {np.round(info['J_agent'], 2).tolist()}, weights {np.round(w, 3).tolist()}, "
                f"location {loc}, cmse_grid {grid_err:.4f}; policy return {ret_mean:.1f}, max coord {maxc:.2f}")
            state["round"] = r + 1
            state["phase"] = "rl"
            save("running" if state["round"] < cfg.rounds else "finishing")
    finally:
        stop.restore()

    # final evaluation of the constraint and of the last policy
    trajs, rets = _rollout_coords(ppo, eval_env, spec.coord, cfg.eval_episodes, seed=seed * 1_000_003 + 999_999,
                                  deterministic=True)
    loc = _location(net, spec, xmin, xmax)
    vals = net.numpy(spec.grid)
    summary: dict[str, Any] = {
        "env": spec.name, "seed": seed, "n_expert": len(expert), "location": loc, "true_location": spec.true_location,
        "cmse_location": (cmse_location(loc, spec.true_location) if loc is not None and spec.true_location is not None
                          else None),
        "cmse_grid": cmse_grid(spec.true_indicator(spec.grid), vals),
        "final_policy": {"mean_return": float(np.mean(rets)),
                         "mean_max_coord0": float(np.mean([t[:, 0].max() for t in trajs])),
                         "fraction_violating": float(np.mean([np.any(spec.true_indicator(t) > 0) for t in trajs]))},
        "lambda": ppo.lam, "ppo_steps": ppo.num_steps, "history": state["history"], "config": cfg.to_dict(),
    }
    save("complete")
    st = load_checkpoint(ckpt)["state"]
    summary["runtime_s"] = float(st["wall_time_s"])
    summary["sessions"] = len(st["sessions"])
    save_checkpoint({"state_dict": net.state_dict(), "dim": k, "hidden": list(cfg.constraint_hidden)}, out / "constraint.pt")
    with atomic_path(out / "constraint_grid.npz") as tmp:
        np.savez_compressed(tmp, grid=spec.grid, c=vals, truth=spec.true_indicator(spec.grid))
    write_json_file(out / "summary.json", summary)
    log(f"done: location {loc}, cmse_location {summary['cmse_location']}, cmse_grid {summary['cmse_grid']:.4f}, "
        f"runtime {summary['runtime_s']:.0f} s over {summary['sessions']} session(s)")
    ppo.close()
    eval_env.close()
    return summary
