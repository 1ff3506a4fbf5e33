"""R-hat and bulk / tail ESS of the PBICRL sampler on the synthetic benchmark, plus its figures.

Workload: the sampler benchmark's problem (3 groups x 60 trajectories labelled by the worst constraint
entered, margins 0 / 2.9, all 10,800 pairs), default settings (4 chains x 400,000 iterations, flat prior on
[-1000, 1000]), and the same with a narrower prior [-100, 100].

    python benchmarks/bench_diagnostics.py --out runs/bench_diagnostics

Writes per configuration a run directory (summary.json, chains.npz, plots/) and a JSON report with every
R-hat / ESS (``OUT/diagnostics.json`` and ``benchmarks/reports/bench_diagnostics.json``, atomically).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import pbicrl
from pbicrl.analysis.plots import plot_run
from pbicrl.inference.synthetic import make_problem


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=400_000)
    ap.add_argument("--chains", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/bench_diagnostics"))
    ap.add_argument("--report", type=Path, default=Path("benchmarks/reports/bench_diagnostics.json"),
                    help="where the JSON report goes (besides OUT/diagnostics.json)")
    args = ap.parse_args()
    prob = make_problem(60, labels="violations", violation_rate=0.4, seed=0)
    args.out.mkdir(parents=True, exist_ok=True)
    data = prob.dataset.save(args.out / "data.npz")
    truth = dict(zip(prob.dataset.feature_names, prob.true_penalty.tolist()))
    report = {"workload": {"trajectories": prob.dataset.n_trajectories, "groups": prob.dataset.n_groups,
                           "margins": [0.0, 2.9], "iterations": args.iterations, "chains": args.chains,
                           "seed": args.seed, "truth": truth}, "runs": {}}
    for label, bound in (("prior_1000", 1000.0), ("prior_100", 100.0)):
        post = pbicrl.infer(prob.dataset, margins=[0.0, 2.9], iterations=args.iterations, chains=args.chains,
                            seed=args.seed, weight_prior=pbicrl.WeightPrior("flat", -bound, bound), progress=False)
        post.extra["data"]["path"] = str(data)
        run = post.save(args.out / label, overwrite=True)
        plot_run(run, truth=truth)
        print(f"== {label}: flat prior [-{bound:g}, {bound:g}]")
        print(post.table())
        print(post.diagnostics().table())
        report["runs"][label] = {"table": post.table(), "diagnostics": post.diagnostics().to_dict(),
                                 "p_constraint": dict(zip(post.feature_names, post.p_constraint.tolist())),
                                 "runtime_s": post.runtime_s}
    for dst in (args.out / "diagnostics.json", args.report):
        dst.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{dst.name}.", dir=dst.parent)
        with os.fdopen(fd, "w") as fh:
            json.dump(report, fh, indent=2)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600
        os.replace(tmp, dst)
        print(f"wrote {dst}")


if __name__ == "__main__":
    main()
