"""The authors' statistic drifts with chain length (issue 29, item 1).

``--sampler authors`` on the shipped point mass the paper's way (Eq. 7 over 60 random pairs per group pair,
the paper's margins m12 = 0, m23 = 2.9, m13 = 6): per seed and chain length, in_red's mean of c*w_p over the kept
draws beside the authors' statistic (mean of the last 500 iterations). Writes a figure of both against chain
length when matplotlib is installed.

    python benchmarks/authors_drift.py [--lengths 100000,400000] [--seeds 0,1] [--figure drift.png]
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np

import pbicrl

PAPER_MARGINS = [[0.0, 0.0, 6.0], [0.0, 0.0, 2.9], [0.0, 0.0, 0.0]]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--lengths", default="100000,400000")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--feature", default="in_red")
    ap.add_argument("--figure", default=None)
    a = ap.parse_args()
    lengths = [int(x) for x in a.lengths.split(",")]
    seeds = [int(x) for x in a.seeds.split(",")]
    ds = pbicrl.load_dataset("point_mass")
    rows = []
    for n in lengths:
        for s in seeds:
            t0 = time.time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                post = pbicrl.infer(ds, sampler="authors", likelihood="pairwise", pairs=60, pairs_seed=s,
                                    margins=PAPER_MARGINS, init_range=(-30, -1), iterations=n, chains=1, seed=s,
                                    progress=False)
            j = post.feature_names.index(a.feature)
            st = post.authors_statistic()
            rows.append({"iterations": n, "seed": s, "posterior_mean": float(post.mean_effective_penalty[j]),
                         "authors_statistic": st["value"][a.feature], "seconds": round(time.time() - t0, 1)})
            print(json.dumps(rows[-1]), flush=True)
    for n in lengths:
        pm = [r["posterior_mean"] for r in rows if r["iterations"] == n]
        au = [r["authors_statistic"] for r in rows if r["iterations"] == n]
        print(f"{n:>9,} iterations, {len(pm)} seeds: {a.feature} mean of kept draws {np.mean(pm):.1f} +- "
              f"{np.std(pm):.1f}; authors' statistic {np.mean(au):.1f} +- {np.std(au):.1f}")
    if a.figure:
        try:
            import matplotlib
            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            print("no figure: pip install matplotlib")
            return
        fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
        for key, mk, lab in (("posterior_mean", "o", "mean of the kept draws"),
                             ("authors_statistic", "s", "authors' statistic (last 500 iterations)")):
            ax.plot([r["iterations"] for r in rows], [r[key] for r in rows], mk, label=lab, alpha=0.7)
        ax.set_xscale("log")
        ax.set_xlabel("chain length (iterations)")
        ax.set_ylabel(f"{a.feature}: c*w_p")
        ax.legend()
        ax.set_title("--sampler authors, shipped point mass:\nin_red drifts with chain length", fontsize=10)
        fig.savefig(a.figure, dpi=120)
        print(f"wrote {a.figure}")


if __name__ == "__main__":
    main()
