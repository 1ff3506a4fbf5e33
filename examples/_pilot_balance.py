"""Shared by the pilot scripts: expected nominal-feature SMDs of a paper-protocol mix, from pools of rollouts.

A mix with good-policy share ``p_good`` is evaluated by reweighting the two pools (each good rollout weighs
``p_good / n_good``, each violating one ``(1 - p_good) / n_violating``); rollouts that miss the goal are dropped,
as the protocol drops them. The SMD of a pair of groups is the difference of weighted means over
``sqrt((var_a + var_b) / 2)`` (weighted, population variances): an approximation of the shipped data's
``navigation.group_feature_balance``, which pools sample variances by group size.
"""
from __future__ import annotations

import numpy as np

PAIRS = ((1, 2), (1, 3), (2, 3))


def expected_smds(good, group, reached, features, p_good):
    """``{feature: {"1-2": d, "1-3": d, "2-3": d}}`` plus ``"max"`` (largest |d|); None if a group is empty.

    ``good``, ``group``, ``reached``: one entry per rollout (1 = good policy; group 1-3; 1 = reached the goal);
    ``features``: name -> per-rollout mean of that feature.
    """
    good, group, reached = (np.asarray(v) for v in (good, group, reached))
    w = np.where(good == 1, p_good / max((good == 1).sum(), 1), (1 - p_good) / (good == 0).sum())
    keep = reached == 1
    out = {}
    for name, x in features.items():
        x = np.asarray(x)
        mu, var = {}, {}
        for k in (1, 2, 3):
            m = keep & (group == k)
            ww = w[m]
            if ww.sum() == 0:
                return None
            mu[k] = np.sum(ww * x[m]) / ww.sum()
            var[k] = np.sum(ww * (x[m] - mu[k]) ** 2) / ww.sum()
        out[name] = {f"{a}-{b}": float((mu[a] - mu[b]) / np.sqrt((var[a] + var[b]) / 2)) for a, b in PAIRS}
    out["max"] = max(abs(v) for name in features for v in out[name].values())
    return out
