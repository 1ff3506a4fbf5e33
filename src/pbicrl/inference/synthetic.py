"""Synthetic problems with known constraints, for tests, benchmarks and examples.

Trajectories are random walks of per-state features; each feature is a constraint indicator or a
continuous nominal feature. Trajectories are grouped by their true length-normalised return, best first,
so the ranking is exactly what the true weights imply (optionally with Bradley-Terry noise).

Sizes are checked before anything is generated: a request whose features cannot fit in this process's
memory (:func:`pbicrl.inference.data.memory_limit_bytes`), or of more than :data:`MAX_TRAJECTORIES` trajectories, is an
error naming the argument, not an out-of-memory kill minutes later.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl.inference.data import Dataset, format_bytes, memory_limit_bytes

__all__ = ["SyntheticProblem", "make_problem", "make_wall_problem", "make_region_problem", "MAX_TRAJECTORIES"]

MAX_TRAJECTORIES = 10_000_000
"""Most trajectories one call generates (they are drawn one by one in Python: more would take hours)."""


def _group_sizes(n_per_group: int | ArrayLike, n_groups: int) -> NDArray[np.int64]:
    """Trajectories per group as positive integers, one per group; errors name ``n_per_group``."""
    if isinstance(n_groups, bool) or not isinstance(n_groups, (int, np.integer)) or n_groups < 2:
        raise ValueError(f"n_groups: expected an integer >= 2, got {n_groups!r}")
    raw = np.asarray(n_per_group)
    if raw.dtype.kind not in "iuf" or raw.ndim > 1 or not np.all(np.isfinite(raw)) or np.any(raw != np.round(raw)):
        raise ValueError(f"n_per_group: expected a positive integer or one per group, got {n_per_group!r}")
    if raw.ndim == 1 and raw.size != n_groups:
        raise ValueError(f"n_per_group: expected one count per group ({n_groups}), got {raw.size}")
    if np.any(raw < 1):
        raise ValueError(f"n_per_group: expected positive counts, got {raw.tolist()}")
    if np.any(raw > MAX_TRAJECTORIES):
        raise ValueError(f"n_per_group: {int(np.max(raw)):,} trajectories per group is more than the "
                         f"{MAX_TRAJECTORIES:,} one dataset may have")
    return np.broadcast_to(raw.astype(np.int64), (n_groups,)).copy()


def _check_size(n_total: int, mean_length: float, n_columns: int, what: str = "n_per_group") -> None:
    """Refuse a dataset that cannot be generated: too many trajectories, or features beyond memory."""
    if n_total > MAX_TRAJECTORIES:
        raise ValueError(f"{what}: {n_total:,} trajectories in all is more than {MAX_TRAJECTORIES:,}; ask for fewer")
    # features, their stacked copy and the validated copy (float64), plus ~1 KiB of Python objects each
    need = n_total * (3.0 * mean_length * n_columns * 8 + 1024)
    limit = memory_limit_bytes()
    if need > limit:
        per = max(1, int(limit / max(need / n_total, 1.0)))
        raise ValueError(f"{what}: {n_total:,} trajectories in all need about {format_bytes(need)} of memory, more than "
                         f"the {format_bytes(limit)} this process can allocate; ask for at most {per:,} in all")


@dataclass(frozen=True, eq=False)
class SyntheticProblem:
    """A dataset together with the truth that generated it.

    Attributes
    ----------
    dataset : Dataset
    true_weights : ndarray (d,)
        :math:`w = w_n + c \\circ w_p`.
    true_indicators : ndarray (d,) int
        :math:`c`.
    true_penalty : ndarray (d,)
        :math:`c \\circ w_p`.
    """

    dataset: Dataset
    true_weights: NDArray[np.float64]
    true_indicators: NDArray[np.int64]
    true_penalty: NDArray[np.float64]


def make_problem(
    n_per_group: int | ArrayLike = 60,
    *,
    n_groups: int = 3,
    nominal_weights: ArrayLike = (1.0, 0.0, 0.0, -1.0),
    penalty: ArrayLike = (0.0, -10.0, -100.0, 0.0),
    length_range: tuple[int, int] = (20, 60),
    violation_rate: float = 0.15,
    noise: float = 0.0,
    labels: str = "return",
    seed: int | np.random.Generator | None = 0,
) -> SyntheticProblem:
    """Generate grouped demonstrations whose true constraint set is ``penalty != 0``.

    Features with non-zero ``penalty`` are binary "inside region" indicators (a trajectory enters the region
    with probability ``violation_rate`` per trajectory and then stays a random number of steps); the others are
    smooth positive features. Trajectories are sorted by true mean return (plus Gumbel noise of scale
    ``noise`` if > 0, i.e. Bradley-Terry-consistent ranking noise) and cut into ``n_groups`` groups.

    Parameters
    ----------
    n_per_group : int or sequence of int
        Trajectories per group.
    n_groups : int
    nominal_weights, penalty : array-like (d,)
        Known :math:`w_n` and true :math:`c \\circ w_p`.
    length_range : (int, int)
        Trajectory lengths drawn uniformly in this range.
    violation_rate : float
        Probability that a trajectory enters each constraint region.
    noise : float
        Ranking noise scale (0 = rank exactly by true return; ``labels="return"`` only).
    labels : {"return", "violations"}
        ``"return"``: sort by (noisy) true mean return and cut into groups of ``n_per_group``.
        ``"violations"``: as the paper labels its demonstrations, group 1 = no constraint entered, group
        ``k+1`` = the ``k``-th mildest constraint is the worst one entered (needs ``n_groups`` = number of
        constraints + 1); trajectories are generated until every group has ``n_per_group``.
    seed : int or Generator
    """
    rng = np.random.default_rng(seed)
    wn = np.asarray(nominal_weights, dtype=np.float64)
    wp = np.asarray(penalty, dtype=np.float64)
    if wn.shape != wp.shape or wn.ndim != 1:
        raise ValueError("nominal_weights and penalty must be 1-D arrays of the same length")
    sizes = _group_sizes(n_per_group, n_groups)
    n_total = int(sizes.sum())
    d = wn.size
    lo, hi = length_range
    if not (isinstance(lo, (int, np.integer)) and isinstance(hi, (int, np.integer)) and 1 <= lo <= hi):
        raise ValueError(f"length_range: expected integers 1 <= low <= high, got {length_range!r}")
    _check_size(n_total, (lo + hi) / 2, d)
    constraint = wp != 0
    if labels not in ("return", "violations"):
        raise ValueError(f"labels: expected 'return' or 'violations', got {labels!r}")
    cidx = np.flatnonzero(constraint)
    if labels == "violations" and n_groups != cidx.size + 1:
        raise ValueError(f"labels='violations': n_groups must be the number of constraints + 1 = {cidx.size + 1}")
    severity = cidx[np.argsort(-wp[cidx])]  # mildest (least negative) first

    def one() -> NDArray[np.float64]:
        T = int(rng.integers(length_range[0], length_range[1] + 1))
        f = np.empty((T, d))
        for j in range(d):
            if constraint[j]:
                col = np.zeros(T)
                if rng.random() < violation_rate:
                    start = int(rng.integers(0, T))
                    stay = int(rng.integers(1, max(2, T // 4)))
                    col[start:start + stay] = 1.0
                f[:, j] = col
            else:
                f[:, j] = np.abs(rng.normal(0.5, 0.3)) + 0.1 * rng.standard_normal(T).cumsum() / np.sqrt(T)
        return f

    w = wn + wp
    if labels == "return":
        feats = [one() for _ in range(n_total)]
        ret = np.array([f.mean(axis=0) @ w for f in feats])
        score = ret + (rng.gumbel(0.0, noise, n_total) if noise > 0 else 0.0)
        order = np.argsort(-score, kind="stable")
        group = np.empty(n_total, dtype=np.int64)
        group[order] = np.repeat(np.arange(1, n_groups + 1), sizes)
    else:
        buckets: list[list[NDArray[np.float64]]] = [[] for _ in range(n_groups)]
        for _ in range(1000 * n_total):
            if all(len(b) >= sizes[k] for k, b in enumerate(buckets)):
                break
            f = one()
            entered = [k for k, j in enumerate(severity) if f[:, j].any()]
            g = 0 if not entered else max(entered) + 1
            if len(buckets[g]) < sizes[g]:
                buckets[g].append(f)
        else:
            raise ValueError("labels='violations': could not fill every group; raise violation_rate")
        feats = [f for b in buckets for f in b]
        group = np.repeat(np.arange(1, n_groups + 1), sizes)
    names = [f"constraint{j}" if constraint[j] else f"feature{j}" for j in range(d)]
    ds = Dataset.from_trajectories(feats, group, feature_names=names, nominal_weights=wn)
    return SyntheticProblem(ds, w, constraint.astype(np.int64), wp)


def make_wall_problem(
    n_per_group: int = 50,
    *,
    wall: float = 8.0,
    length: int = 200,
    seed: int | np.random.Generator | None = 0,
) -> SyntheticProblem:
    """1-D forward motion with an unobserved wall at ``x >= wall`` (the HalfCheetah/Ant setting).

    Known features per step: forward displacement and squared action norm, nominal weights ``[20, -0.1]``.
    Group 1 trajectories run up to the wall and stop short of it (between 90% and 99.5% of ``wall``);
    group 2 trajectories cross it. States: ``x`` (k = 1).
    ``true_penalty`` holds the known features' zeros; the wall itself is described by ``wall``.
    """
    _group_sizes(n_per_group, 2)
    if isinstance(length, bool) or not isinstance(length, (int, np.integer)) or length < 1:
        raise ValueError(f"length: expected a positive integer, got {length!r}")
    _check_size(2 * int(n_per_group), length, 3)
    rng = np.random.default_rng(seed)
    feats, states, group = [], [], []
    for g in (1, 2):
        for _ in range(n_per_group):
            # good demonstrators run up to the wall and stop just short of it, as SAC does with the penalty
            end = rng.uniform(0.9 * wall, 0.995 * wall) if g == 1 else rng.uniform(1.15 * wall, 3.0 * wall)
            v = end / length
            dx = np.clip(v + 0.3 * v * rng.standard_normal(length), 0.0, None)
            x = np.cumsum(dx)
            if g == 1:
                x = np.minimum(x, end)
                dx = np.diff(np.concatenate([[0.0], x]))
            act = (rng.uniform(0.2, 1.0) + 0.1 * rng.standard_normal(length)) ** 2
            feats.append(np.c_[dx, act])
            states.append(x[:, None])
            group.append(g)
    ds = Dataset.from_trajectories(feats, group, states=states, feature_names=["forward_displacement", "action_sq_norm"],
                                   nominal_weights=[20.0, -0.1])
    return SyntheticProblem(ds, np.array([20.0, -0.1]), np.zeros(2, dtype=np.int64), np.zeros(2))


def make_region_problem(
    n_per_group: int = 40,
    *,
    region: str = "ball",
    length: int = 40,
    seed: int | np.random.Generator | None = 0,
) -> tuple[SyntheticProblem, NDArray[np.float64]]:
    """2-D straight-ish paths between random points on the edge of [0, 10]^2; group 2 = the path enters a hidden region.

    ``region="ball"``: open disc, centre (5, 5), radius 2 (true parameters ``[5, 5, 2]``);
    ``region="box"``: closed box [3.5, 6.5] x [4, 6] (true parameters ``[3.5, 4, 6.5, 6]``).
    Known feature: step length (nominal weight -1). Returns the problem and the true parameters.
    """
    _group_sizes(n_per_group, 2)
    if isinstance(length, bool) or not isinstance(length, (int, np.integer)) or length < 2:
        raise ValueError(f"length: expected an integer >= 2, got {length!r}")
    _check_size(2 * int(n_per_group), length, 3)
    rng = np.random.default_rng(seed)
    if region == "ball":
        truth = np.array([5.0, 5.0, 2.0])

        def inside(p: NDArray) -> NDArray:
            return np.sum((p - truth[:2]) ** 2, axis=1) < truth[2] ** 2
    elif region == "box":
        truth = np.array([3.5, 4.0, 6.5, 6.0])

        def inside(p: NDArray) -> NDArray:
            return np.all((p >= truth[:2]) & (p <= truth[2:]), axis=1)
    else:
        raise ValueError(f"region: expected 'ball' or 'box', got {region!r}")
    buckets: list[list[tuple[NDArray, NDArray]]] = [[], []]
    for _ in range(200 * n_per_group):
        if min(len(b) for b in buckets) >= n_per_group:
            break
        a, b = _perimeter_point(rng), _perimeter_point(rng)
        if np.linalg.norm(b - a) < 5.0:
            continue
        s = np.linspace(0, 1, length)[:, None]
        pts = a + s * (b - a) + np.cumsum(0.05 * rng.standard_normal((length, 2)), axis=0)
        g = int(inside(pts).any())
        if len(buckets[g]) < n_per_group:
            step = np.r_[0.0, np.linalg.norm(np.diff(pts, axis=0), axis=1)]
            buckets[g].append((step[:, None], pts))
    feats = [f for b in buckets for f, _ in b]
    states = [p for b in buckets for _, p in b]
    group = np.repeat([1, 2], [len(buckets[0]), len(buckets[1])])
    ds = Dataset.from_trajectories(feats, group, states=states, feature_names=["step_length"], nominal_weights=[-1.0])
    return SyntheticProblem(ds, np.array([-1.0]), np.zeros(1, dtype=np.int64), np.zeros(1)), truth


def _perimeter_point(rng: np.random.Generator) -> NDArray[np.float64]:
    u = rng.uniform(0, 10)
    return [np.array([0.0, u]), np.array([10.0, u]), np.array([u, 0.0]), np.array([u, 10.0])][int(rng.integers(4))]
