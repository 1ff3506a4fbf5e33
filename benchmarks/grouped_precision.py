"""Precision of the grouped likelihood's quadrature: one group's :math:`\\log P_k` against the same integrals with
a 10x finer step and a much stricter stopping tolerance, over many kinds of groups.

    python benchmarks/grouped_precision.py                      # 4,000 groups, seed 0
    python benchmarks/grouped_precision.py --groups 20000 --json out.json

Groups: sizes 2 .. 10,000 (log-uniform); returns uniform, normal, exponential, two clusters or all tied, spread
0.001 .. 1e4 nats; shifted so that the group's order ranges from near-impossible to near-certain
(``log Lambda`` moved by -30 .. +30 around the group's own logsumexp). The default rule is
:func:`pbicrl.inference.likelihood_kernels.group_term` (per-item path; the binned path evaluates the same rule
at the same nodes, equal to it to 1e-12 in ``tests/inference/test_grouped_likelihood.py``); the reference follows
the same branches (direct or complement form) with ``step / 10`` and tolerance ``1e-13``. Printed and written:
the worst and the 99.9% quantile of the relative error of :math:`\\log P_k`, and the absolute error in nats.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np


def _reference(x: np.ndarray, K: object, fine: float = 10.0) -> float:
    """``group_term``'s branches with a ``fine``-times smaller step and tolerance 1e-13."""
    n = x.size
    if n == 1:
        return -float(np.logaddexp(0.0, -x[0]))
    buf = np.empty((2, n))
    u0, b = buf[0], buf[1]
    step, smax, acc = K._G_STEP / fine, K._G_STEP_MAX / fine, 1e-13
    s0, g0, g2 = K._pl_mode(False, x)
    sig = 1.0 / math.sqrt(-g2)
    if g0 + math.log(sig) + K._LOG_SQRT_2PI < K._G_SWITCH:
        lp = K._pl_integral(False, x, s0, sig, *K._G_MAP_DIRECT, step, smax, acc, u0, b)
        if lp <= math.log(0.9):
            return lp
    sc, c0, c2 = K._pl_mode(True, x)
    if c0 == -np.inf:
        return 0.0
    sigc = 1.0 / math.sqrt(-c2) if c2 < 0.0 else 1.0
    lq = K._pl_integral(True, x, sc, sigc, *K._G_MAP_COMP, step, smax, acc, u0, b)
    if lq <= math.log(0.5):
        return math.log1p(-math.exp(lq))
    return K._pl_integral(False, x, s0, sig, *K._G_MAP_DIRECT, step, smax, acc, u0, b)


def _group(rng: np.random.Generator) -> np.ndarray:
    n = int(np.exp(rng.uniform(math.log(2), math.log(10_000))))
    spread = float(np.exp(rng.uniform(math.log(1e-3), math.log(1e4))))
    kind = rng.integers(5)
    if kind == 0:
        a = rng.uniform(0.0, spread, n)
    elif kind == 1:
        a = rng.normal(0.0, spread / 4.0, n)
    elif kind == 2:
        a = -rng.exponential(spread / 4.0, n)
    elif kind == 3:
        a = np.where(rng.random(n) < 0.5, 0.0, spread) + rng.normal(0.0, 0.01, n)
    else:
        a = np.zeros(n)
    lse = float(np.logaddexp.reduce(a))
    return a - lse + rng.uniform(-30.0, 30.0)  # x = a - log Lambda


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--groups", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from pbicrl.inference import likelihood_kernels as K

    rng = np.random.default_rng(args.seed)
    errs: dict[str, list[tuple[float, float, int, float, float]]] = {"per_item": [], "binned": []}
    t0 = time.perf_counter()
    for _ in range(args.groups):
        x = _group(rng)
        ref = _reference(x, K)
        got = {"per_item": K.group_term(x, np.empty((2, x.size)))}
        if x.size >= K._GB_MIN:
            cen, mom, nb, sp = K._gb_moments(x, np.arange(x.size), np.empty((2, x.size)))
            if nb > 0:
                got["binned"] = K._gb_term(x.size, 0.0, cen, mom, nb, sp, np.empty((3, x.size)))
        for path, g in got.items():
            if not (math.isfinite(g) and math.isfinite(ref)):
                if g != ref:
                    raise SystemExit(f"{path}: non-finite mismatch: n={x.size} got {g} reference {ref}")
                continue
            e = abs(g - ref)
            r = e / max(abs(ref), 1e-300) if ref != 0.0 else (0.0 if g == 0.0 else math.inf)
            errs[path].append((r, e, int(x.size), float(np.ptp(x)), ref))
    out: dict = {"seed": args.seed, "constants": {"step": K._G_STEP, "step_max": K._G_STEP_MAX,
                                                  "accept": K._G_ACCEPT, "drop": K._G_DROP,
                                                  "map_direct": K._G_MAP_DIRECT, "map_comp": K._G_MAP_COMP,
                                                  "binned_order": K._GB_ORDER, "bin_width": K._GB_WIDTH}}
    for path, rows in errs.items():
        arr = np.array([r[:2] for r in rows])
        w = max(rows, key=lambda r: r[0])
        out[path] = {"groups": len(rows), "worst_relative": float(arr[:, 0].max()),
                     "q999_relative": float(np.quantile(arr[:, 0], 0.999)),
                     "worst_absolute_nats": float(arr[:, 1].max()),
                     "worst_group": {"relative": w[0], "absolute": w[1], "n": w[2], "spread": w[3], "log_p": w[4]}}
    out["seconds"] = time.perf_counter() - t0
    print(json.dumps(out, indent=1))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
