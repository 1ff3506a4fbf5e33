"""The ICRL benchmark's command line.

``pbicrl benchmark icrl run|train|demos|report|status`` (mounted on ``pbicrl``), and
``python -m pbicrl.cli.icrl_benchmark`` (the same as ``pbicrl benchmark icrl train``, kept for the running trainings):

``train --out DIR --run TASK:METHOD:SEED:STEPS [--run ...] [--inferred-run RUN] [--cost-mode MODE] [--icl-budget B]``
    train the listed runs one after another (:func:`pbicrl.experiments.icrl_benchmark.train_policy`; each
    resumable, finished ones skipped);
``demos --task TASK --expert CKPT --unconstrained CKPT --out FILE.npz``
    ranked demonstrations (:func:`pbicrl.experiments.icrl_demos.generate_ranked_demos`);
``report --runs DIR --out DIR``
    the benchmark's table and figures (:func:`pbicrl.experiments.icrl_report.build_report`);
``run --out DIR [--tasks T,...] [--seeds 5] [--methods M,...] [--executor local|serial|ray] [--workers N]``
    the whole benchmark: infer each task's wall, train every run at its budget, write the report
    (:func:`pbicrl.experiments.icrl_run.run_benchmark`; ``--dry-run`` lists the runs);
``status --runs DIR``
    every run's state: done, training (with its time left), stopped (rerun to resume)
    (:func:`pbicrl.experiments.icrl_report.run_status`).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["add_subcommands", "main"]


def _parse_job(text: str) -> tuple[str, str, int, int]:
    parts = text.split(":")
    if len(parts) != 4:
        raise ValueError(f"--run: expected TASK:METHOD:SEED:STEPS, got {text!r}")
    task, method, seed, steps = parts
    try:
        return task, method, int(seed), int(float(steps))
    except ValueError:
        raise ValueError(f"--run: SEED and STEPS must be integers in {text!r}") from None


def _train_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="root directory of the runs")
    p.add_argument("--run", action="append", required=True, metavar="TASK:METHOD:SEED:STEPS",
                   help="a run to train (repeatable; trained in order), e.g. halfcheetah:ppo_lag_true:0:3000000; "
                        "METHOD: ppo, ppo_lag_true, ppo_lag_inferred, icl (STEPS = ICL's total PPO steps; the "
                        "benchmark's: halfcheetah 4500000, ant and walker 2500000, pendulum and swimmer 2000000)")
    p.add_argument("--checkpoint-every", type=int, default=2, help="updates between checkpoints (default 2)")
    p.add_argument("--eval-every", type=int, default=10, help="updates between evaluations (default 10)")
    p.add_argument("--inferred-run", type=Path, default=None,
                   help="ppo_lag_inferred: the run directory of pbicrl infer whose constraint is the cost")
    p.add_argument("--cost-mode", default="conservative",
                   help="ppo_lag_inferred: how the posterior becomes a cost (default conservative; see "
                        "pbicrl.envs.inferred_cost)")
    p.add_argument("--icl-budget", default="default",
                   help="icl: ICL's preset (default 'default'; its rounds, scaled to STEPS, see "
                        "pbicrl.experiments.icrl_benchmark.icl_config)")


def _train(args: argparse.Namespace) -> int:
    from pbicrl.experiments.icrl_benchmark import expert_config, icl_config, train_policy

    jobs = [_parse_job(j) for j in args.run]
    for task, method, seed, steps in jobs:
        if method == "icl":  # fail on a bad task, method or budget before hours of training
            icl_config(task, steps, args.icl_budget)
        else:
            expert_config(task, method)
        if method == "ppo_lag_inferred" and args.inferred_run is None:
            raise ValueError("--inferred-run: method ppo_lag_inferred needs the run directory of pbicrl infer")
    if args.inferred_run is not None and not any(m == "ppo_lag_inferred" for _, m, _, _ in jobs):
        raise ValueError("--inferred-run: only for method ppo_lag_inferred")
    for task, method, seed, steps in jobs:
        inferred = args.inferred_run if method == "ppo_lag_inferred" else None
        train_policy(task, method, seed, args.out, steps, checkpoint_every=args.checkpoint_every,
                     eval_every=args.eval_every, inferred_run=inferred, cost_mode=args.cost_mode,
                     icl_budget=args.icl_budget, log=lambda s: print(time.strftime("%H:%M:%S"), s, flush=True))
    return 0


def _demos(args: argparse.Namespace) -> int:
    from pbicrl.experiments.icrl_demos import SOURCES, DemoRules, generate_ranked_demos

    rules = DemoRules.for_task(args.task, args.brief_max_steps, args.through_min_steps)
    sources = SOURCES if args.sources is None else tuple(s.strip() for s in args.sources.split(",") if s.strip())
    parts = ["pbicrl", "benchmark", "icrl", "demos", "--task", args.task, "--expert", str(args.expert),
             "--unconstrained", str(args.unconstrained), "--handover", str(args.handover or args.unconstrained),
             "--out", str(args.out), "--n-per-group",
             str(args.n_per_group), "--seed", str(args.seed), "--brief-max-steps", str(rules.brief_max_steps),
             "--through-min-steps", str(rules.through_min_steps), "--noise-sd", f"{args.noise_sd:g}",
             "--sources", ",".join(sources), "--max-episodes", str(args.max_episodes)]
    command = " ".join(shlex.quote(a) for a in parts)  # every setting spelled out, defaults included
    _, rec = generate_ranked_demos(args.task, args.expert, args.unconstrained, args.out, handover=args.handover,
                                   n_per_group=args.n_per_group, seed=args.seed, rules=rules, noise_sd=args.noise_sd,
                                   sources=sources, max_episodes=args.max_episodes, command=command,
                                   log=None if args.quiet else lambda s: print(s, file=sys.stderr, flush=True))
    g = rec["groups"]
    print(f"wrote {args.out} ({rec['file_bytes'] / 2**20:.2f} MiB): groups {g['1']['n']}, {g['2']['n']}, {g['3']['n']} "
          f"from {rec['episodes_generated']} episodes")
    return 0


def _report(args: argparse.Namespace) -> int:
    from pbicrl.experiments.icrl_report import build_report

    methods = _csv(args.methods)
    kw = {} if methods is None else {"methods": methods}
    res = build_report(args.runs, args.out, tasks=_csv(args.tasks), seeds_planned=args.seeds,
                       figures=not args.no_figures, **kw)
    print(f"wrote {Path(args.out) / 'report.md'}; missing rows: {len(res['missing'])}, runs in progress: "
          f"{len(res['in_progress'])}")
    return 0


def _csv(text: str | None) -> list[str] | None:
    return None if text is None else [t.strip() for t in text.split(",") if t.strip()]


def _run(args: argparse.Namespace) -> int:
    from pbicrl.experiments.icrl_run import plan_jobs, run_benchmark

    jobs, skipped = plan_jobs(_csv(args.tasks), args.seeds, _csv(args.methods))
    if args.dry_run:
        for j in jobs:
            print(j.name)
        for s in skipped:
            print(f"left out: {s}")
        print(f"{len(jobs)} runs, {sum(j.steps for j in jobs) / 1e6:.1f} M environment steps in all")
        return 0
    res = run_benchmark(args.out, tasks=_csv(args.tasks), seeds=args.seeds, methods=_csv(args.methods),
                        executor=args.executor, workers=args.workers, infer_dir=args.infer_dir,
                        report_dir=None if args.no_report else (args.report or args.out / "report"),
                        infer_max_time=args.infer_max_time)
    n = {k: sum(o["status"] == k for o in res["jobs"]) for k in ("done", "busy", "failed")}
    print(f"{len(res['jobs'])} runs: {n['done']} done, {n['busy']} trained by another process, {n['failed']} failed"
          + (f"; report {res['report']}" if res["report"] else ""))
    for o in res["jobs"]:
        if o["status"] == "failed":
            print(f"failed: {o['job']}: {o['error'].splitlines()[0]}", file=sys.stderr)
    return 1 if n["failed"] else 0


def _hours(s: float | None) -> str:
    return "-" if s is None else f"{s / 3600:.2f}"


def _status(args: argparse.Namespace) -> int:
    import json

    from pbicrl.experiments.icrl_report import run_status

    rows = run_status(args.runs)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    if not rows:
        print(f"no runs under {args.runs}")
        return 0
    w = max(len(r["run"]) for r in rows)
    print(f"{'run':<{w}}  {'state':<8}  {'steps':>10}  {'target':>10}  {'violation':>9}  {'feasible':>9}  "
          f"{'wall h':>6}  {'left h':>6}")
    for r in rows:
        viol = "-" if r["violation_rate"] is None else f"{r['violation_rate']:.2f}"
        feas = "-" if r["feasible_reward"] is None else f"{r['feasible_reward']:.0f}"
        print(f"{r['run']:<{w}}  {r['state']:<8}  {r['steps'] or 0:>10,}  {r['target'] or 0:>10,}  {viol:>9}  "
              f"{feas:>9}  {_hours(r['wall_s']):>6}  {_hours(r['eta_s']):>6}")
    n = {k: sum(r["state"] == k for r in rows) for k in ("done", "training", "stopped", "started")}
    print(f"{len(rows)} runs: {n['done']} done, {n['training']} training, {n['stopped']} stopped (rerun its train "
          f"command to resume), {n['started']} started; violation and feasible: the last evaluation; left: at the "
          "run's average pace so far")
    return 0


def add_subcommands(sub: Any) -> None:
    """Register ``pbicrl benchmark icrl {run,train,demos,report,status}`` (imports nothing optional until it runs)."""
    from pbicrl.cli.argtypes import nonneg_int, positive_float, positive_int

    p = sub.add_parser("benchmark", help="benchmarks: 'icrl' (the ICRL benchmark of Liu et al., ICLR 2023)",
                       description="Benchmarks of pbicrl against the field's.")
    suites = p.add_subparsers(dest="suite", required=True, metavar="SUITE")
    icrl = suites.add_parser("icrl", help="the ICRL benchmark's virtual tasks (Blocked Half-Cheetah, ...)",
                             description="The five virtual tasks of the ICRL benchmark: train reference policies, "
                                         "generate ranked demonstrations, report.")
    acts = icrl.add_subparsers(dest="action", required=True, metavar="ACTION")
    rn = acts.add_parser("run", help="the whole benchmark: walls, every run at its budget, the report; resumable",
                         description="Infer each task's wall from its shipped demonstrations, train every (task, "
                                     "method, seed) at the documented budget (pbicrl.experiments.icrl_run.BUDGETS), "
                                     "then write the report. Resumable: rerun the same command; finished runs are "
                                     "skipped, stopped ones continue from their checkpoints.")
    rn.add_argument("--out", required=True, type=Path, help="root of the training runs")
    rn.add_argument("--tasks", default=None, help="comma-separated tasks (default all five)")
    rn.add_argument("--seeds", type=positive_int, default=5, help="seeds per row (default 5)")
    rn.add_argument("--methods", default=None,
                    help="comma-separated methods (default ppo,ppo_lag_true,ppo_lag_inferred,icl)")
    rn.add_argument("--executor", choices=["local", "serial", "ray"], default="local",
                    help="local process pool (default), serial, or Ray (pip install \"pbicrl[ray]\"; --out must be "
                         "on a disk every worker sees)")
    rn.add_argument("--workers", type=positive_int, default=None, help="runs at once (local; default: the cores)")
    rn.add_argument("--infer-dir", type=Path, default=None,
                    help="the walls' pbicrl infer runs: reused when there, else inferred (default OUT/infer)")
    rn.add_argument("--infer-max-time", type=positive_float, default=1500.0,
                    help="seconds a wall inference may sample (default 1500)")
    rn.add_argument("--report", type=Path, default=None,
                    help="where report.md, results.json and figures/ go (default OUT/report)")
    rn.add_argument("--no-report", action="store_true", help="train only")
    rn.add_argument("--dry-run", action="store_true", help="list the runs and their steps; train nothing")
    rn.set_defaults(func=_run)
    t = acts.add_parser("train", help="train runs (ppo, ppo_lag_true, ppo_lag_inferred, icl); resumable")
    _train_options(t)
    t.set_defaults(func=_train)
    d = acts.add_parser("demos", help="ranked demonstrations (groups 1 never crosses, 2 briefly, 3 through)",
                        description="Roll out a mix of policies from one start distribution and label each "
                                    "episode by what it did with the true wall.")
    d.add_argument("--task", required=True, help="halfcheetah, ant, pendulum, walker, swimmer")
    d.add_argument("--expert", required=True, type=Path, help="checkpoint of the ppo_lag_true run (best.pt)")
    d.add_argument("--unconstrained", required=True, type=Path, help="checkpoint of the ppo run")
    d.add_argument("--handover", type=Path, default=None,
                   help="checkpoint the 'switch' source starts with before handing over to the expert near the "
                        "wall (default: --unconstrained; an early checkpoint of the ppo run is slower, so the "
                        "expert can turn it back after a brief crossing)")
    d.add_argument("--out", required=True, type=Path, help="the .npz to write (the record goes beside it, .json)")
    d.add_argument("--n-per-group", type=positive_int, default=100, help="episodes per group (default 100)")
    d.add_argument("--seed", type=nonneg_int, default=0, help="seed (default 0)")
    d.add_argument("--brief-max-steps", type=positive_int, default=None,
                   help="group 2: at most this many violating steps (default 10%% of the episode length)")
    d.add_argument("--through-min-steps", type=positive_int, default=None,
                   help="group 3: at least this many violating steps (default half the episode length)")
    d.add_argument("--noise-sd", type=float, default=0.5, help="action noise of expert_noise (default 0.5)")
    d.add_argument("--sources", default=None, help="comma-separated sources (default all: expert, expert_noise, "
                                                   "unconstrained, switch)")
    d.add_argument("--max-episodes", type=positive_int, default=3000, help="give up after this many (default 3000)")
    d.add_argument("--quiet", action="store_true", help="no progress lines")
    d.set_defaults(func=_demos)
    r = acts.add_parser("report", help="table and figures from the run directories",
                        description="Violation rate and feasible cumulative reward per task and method.")
    r.add_argument("--runs", required=True, type=Path, help="root of the training runs (train --out)")
    r.add_argument("--out", type=Path, default=Path("docs/benchmarks/icrl"),
                   help="where report.md, results.json and figures/ go (default docs/benchmarks/icrl)")
    r.add_argument("--tasks", default=None, help="comma-separated tasks (default all five)")
    r.add_argument("--seeds", type=positive_int, default=5, help="seeds planned per row (default 5)")
    r.add_argument("--methods", default=None,
                   help="comma-separated methods, the rows per task (default ppo,ppo_lag_true,ppo_lag_inferred,icl)")
    r.add_argument("--no-figures", action="store_true", help="no figures")
    r.set_defaults(func=_report)
    st = acts.add_parser("status", help="every run's state: done, training (time left), stopped",
                         description="Where every run under --runs stands: done, training (its lock names a live "
                                     "process; the time left at its pace so far), stopped (rerun to resume).")
    st.add_argument("--runs", required=True, type=Path, help="root of the training runs (train --out)")
    st.add_argument("--json", action="store_true", help="print the rows as JSON")
    st.set_defaults(func=_status)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m pbicrl.cli.icrl_benchmark --out DIR --run TASK:METHOD:SEED:STEPS [--run ...]``: train
    the listed runs one after another (each resumable; finished ones are skipped)."""
    p = argparse.ArgumentParser(prog="python -m pbicrl.cli.icrl_benchmark", description=main.__doc__)
    _train_options(p)
    args = p.parse_args(argv)
    try:
        return _train(args)
    except (ValueError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # an ICL run stopped by SIGTERM/SIGINT has checkpointed: rerun to resume
        print(f"stopped: {exc}", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
