"""Identified-posterior acceptance check: default settings, 5 seeds, three data sets; sign any; prior scale x10, /10.

    python benchmarks/identified_posterior_check.py [ITERATIONS] > out.jsonl

One JSON line per run (selected set, P(c=1), conditional medians, min_penalty, R-hat, runtime). The large
point-mass set is made with the command in docs/envs.md (runs/point_mass_large.npz).
"""
import json, sys, time, warnings
import numpy as np
warnings.simplefilter("ignore")
import pbicrl
from pbicrl.inference.priors import WeightPrior

ITER = int(sys.argv[1]) if len(sys.argv) > 1 else 20000
sets = {"point_mass": "point_mass", "fetch_reach": "fetch_reach", "point_mass_large": "runs/point_mass_large.npz"}
out = []
def run(name, path, seed, label, **kw):
    ds = pbicrl.load_dataset(path)
    t0 = time.time()
    post = pbicrl.infer(ds, iterations=ITER, chains=2, jobs=1, seed=seed, progress=False, **kw)
    s = post.summary()
    rh = s["posterior"].get("rhat") or {}
    vals = [v for k in rh for v in (rh[k].values() if isinstance(rh[k], dict) else [rh[k]]) if v is not None] if isinstance(rh, dict) else []
    med = s["posterior"]["penalty_given_active"]["median"]
    rec = {"data": name, "seed": seed, "label": label, "selected": s["selected"], "p_c": s["posterior"]["p_constraint"],
           "median_given_c1": med, "min_penalty": {k: v["min_penalty"] for k, v in s["identified"]["features"].items()},
           "rhat": rh, "runtime_s": round(time.time() - t0, 1), "iterations": ITER}
    out.append(rec)
    print(json.dumps(rec), flush=True)
for name, path in sets.items():
    for seed in range(5):
        run(name, path, seed, "default")
for name, path in sets.items():
    run(name, path, 0, "prior_scale x10", weight_prior=WeightPrior(prior_scale=25.0))
    run(name, path, 0, "prior_scale /10", weight_prior=WeightPrior(prior_scale=0.25))
for name, path in sets.items():
    for seed in range(5):
        run(name, path, seed, "sign any", weight_prior=WeightPrior(sign="any"))
