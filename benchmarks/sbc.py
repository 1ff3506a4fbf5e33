"""Simulation-based calibration of the PBICRL sampler: rank histograms (PNG) and uniformity tests (JSON).

Small problems (d = 2 features, 3 groups x 10 trajectories, flat prior on [-3, 3], Bernoulli(1/2)
indicators); each replicate draws (c, w_p) from the prior, simulates data, runs 4 chains of the ``pbicrl``
sampler and ranks the truth among 80 evenly spaced posterior draws. See :mod:`pbicrl.analysis.calibration`.

    python benchmarks/sbc.py                                 # both designs, 1000 replicates each
    python benchmarks/sbc.py --design pairs --replicates 200 --out runs/sbc

``pairs``: explicit Bradley-Terry comparisons, exactly the likelihood's model (tests the sampler).
``groups``: Gumbel-perturbed ranking cut into groups + all-pairs likelihood (tests the model; expected to
be miscalibrated because the all-pairs composite likelihood counts each trajectory many times).

Writes ``OUT/sbc_<design>.json`` and ``OUT/sbc_<design>.png`` (atomically).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pbicrl.analysis.calibration import SBCProblem, SBCResult, run_sbc


def histogram(res: SBCResult, path: Path) -> None:
    """Rank histograms with the 99% band of a uniform histogram."""
    from matplotlib.figure import Figure
    from scipy import stats

    bins = res.tests["bins"]
    R = res.ranks.shape[0]
    lo, hi = stats.binom.ppf([0.005, 0.995], R, 1 / bins)
    q = len(res.names)
    fig = Figure(figsize=(3.0 * q, 2.8), layout="constrained")
    axes = fig.subplots(1, q, squeeze=False)[0]
    for ax, name, t in zip(axes, res.names, res.tests["tests"]):
        counts = np.asarray(t["counts"])
        ax.axhspan(lo, hi, color="0.85", label="99% band (uniform)")
        ax.axhline(R / bins, color="0.4", lw=0.8)
        ax.bar(np.arange(bins), counts, width=0.9, color="C0")
        ax.set_title(f"{name}\nchi2 p={t['chi2_p']:.3f}, KS p={t['ks_p']:.3f}", fontsize=8)
        ax.set_xlabel(f"rank bin (L={res.L})", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel(f"replicates (of {R})", fontsize=8)
    axes[0].legend(fontsize=6, loc="lower left")
    verdict = "PASS" if res.passed(0.01) else "FAIL"
    gp = res.problem.group_pairs
    label = res.problem.design if res.problem.design == "pairs" or gp == "all" else f"groups, {gp} pairs per group pair"
    fig.suptitle(f"SBC, design '{label}': {verdict} (Bonferroni, alpha 0.01)", fontsize=10)
    _atomic(path, lambda p: fig.savefig(p, dpi=110, format="png"))


def _atomic(path: Path, write) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--design", choices=["pairs", "groups", "both"], default="both")
    ap.add_argument("--replicates", type=int, default=1000)
    ap.add_argument("--iterations", type=int, default=20_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--group-pairs", type=int, help="groups design: N random pairs per group pair instead of all")
    ap.add_argument("--power", default="1", help="likelihood power: a number in (0, 1] or 'pairs'")
    ap.add_argument("--likelihood", choices=["pairwise", "grouped"], default="pairwise",
                    help="groups design: inference with the paper's Eq. 7 or the exact grouped likelihood")
    ap.add_argument("--diagnose", action="store_true", help="also record R-hat / ESS of every replicate (needs ArviZ)")
    ap.add_argument("--sign", choices=["any", "negative"], default="any",
                    help="flat prior on [-3, 3] (any) or [-3, 0] (negative: the sampler then moves log|w|)")
    ap.add_argument("--p-joint", type=float, default=0.0, help="probability of the joint weight step")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/reports"))
    args = ap.parse_args()
    designs = ["pairs", "groups"] if args.design == "both" else [args.design]
    for design in designs:
        gp = args.group_pairs if (design == "groups" and args.group_pairs) else "all"
        power = args.power if args.power == "pairs" else float(args.power)
        lik = args.likelihood if design == "groups" else "pairwise"
        problem = SBCProblem(design=design, group_pairs=gp, power=power, likelihood=lik, sign=args.sign)
        tag = design if gp == "all" else f"{design}_pairs{gp}"
        if lik == "grouped":
            tag += "_grouped"
        if power != 1.0:
            tag += f"_power-{args.power}"
        if args.sign != "any":
            tag += f"_{args.sign}"
        if args.p_joint:
            tag += f"_pjoint{args.p_joint:g}"
        t0 = time.perf_counter()

        def tick(r: int, design: str = design, t0: float = t0) -> None:
            if (r + 1) % 50 == 0:
                print(f"[{design}] {r + 1}/{args.replicates} replicates, {time.perf_counter() - t0:.0f} s",
                      file=sys.stderr, flush=True)

        res = run_sbc(problem, n_replicates=args.replicates, iterations=args.iterations, seed=args.seed,
                      diagnose=args.diagnose, progress=tick, p_joint=args.p_joint)
        out = res.to_dict()
        text = json.dumps(out, indent=2) + "\n"
        _atomic(args.out / f"sbc_{tag}.json", lambda p, text=text: Path(p).write_text(text))
        histogram(res, args.out / f"sbc_{tag}.png")
        print(f"design {tag}: {args.replicates} replicates in {res.runtime_s:.0f} s; "
              f"{'PASS' if res.passed(0.01) else 'FAIL'}")
        for name, t in out["tests"].items():
            print(f"  {name:<14} chi2 p={t['chi2_p']:.4f}  KS p={t['ks_p']:.4f}  mean normalised rank "
                  f"{t['mean_rank_normalised']:.3f}  counts {t['counts']}")
        if out["diagnostics"]:
            print(f"  diagnostics: {out['diagnostics']}")
        for name, e in out["conditional"]["features"].items():
            print(f"  penalty[{name}] | c=1: coverage90 {e['coverage90']}  rank chi2 p {e.get('rank_chi2_p')}  "
                  f"KS p {e.get('rank_ks_p')}  ({e['replicates_with_c1']} replicates)")
        print("  P(c=1) reliability: " + "; ".join(
            f"[{r['bin'][0]:.2f},{r['bin'][1]:.2f}] n={r['n']} pred={r['predicted'] if r['predicted'] is None else round(r['predicted'], 3)} "
            f"obs={r['observed'] if r['observed'] is None else round(r['observed'], 3)}"
            for r in out["conditional"]["reliability"]) + f"; Brier {out['conditional']['brier']:.4f}")


if __name__ == "__main__":
    main()
