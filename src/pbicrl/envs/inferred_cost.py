r"""A per-step cost from an inferred constraint: act on a posterior (Safety-Gymnasium's ``info["cost"]``).

:class:`InferredConstraintCost` wraps a Gymnasium environment and adds, at every step, a cost
:math:`c_t \ge 0` for the state the step reached, computed from a posterior over constraints
(:class:`pbicrl.inference.posterior.Posterior` or a run directory read by :func:`pbicrl.io.runs.read_run`). The
reward :math:`r(s) = (w_n + c \circ w_p)^\top \phi(s)` has known features :math:`\phi_j` (columns of the
dataset) and, optionally, parametric constraints :math:`\phi_{\vartheta_m}(s) = 1[s \in R(\vartheta_m)]`
(:mod:`pbicrl.inference.constraints`). Per step the wrapper needs the known features, ``features(obs, info) -> (d,)``,
and for parametric constraints the state, ``state(obs, info) -> (k,)`` (the columns the constraints'
``dims`` index). The shipped environments provide both (:func:`default_step_functions`).

Modes (:data:`MODES`), for the constraints used (default: the selected set, :math:`P(c_j = 1) > 0.5`). The
default mode is ``conservative`` when the posterior has parametric constraints, else ``indicator``.

``conservative`` (default with parametric constraints)
    Safe by construction: a parametric constraint's boundary is put at the edge of the identified region
    nearest the demonstrated safe behaviour, and the posterior says how hard to penalise, not where. The state
    is inside when it is inside the region of *any* kept draw with :math:`c_m = 1` (the union of the identified
    regions); for a wall :math:`x \ge \vartheta` that is :math:`x \ge \min \vartheta`, the lowest threshold
    the posterior allows. When the states the good demonstrations reached are known (``safe_states``; by
    default the best group of the run's own dataset, ``summary.json``'s ``extra.data.path``, when that file is
    there) a wall's boundary is put just beyond the furthest of them instead: the furthest point the good
    demonstrations reach, where the identified interval starts (a soft likelihood lets the posterior's lowest
    draws spill over the demonstrated-safe states; those states are not charged). The cost of a step is
    :math:`\max_m P(c_m = 1 \mid \mathcal D)\,1[s \in R_m]` (known features:
    :math:`P(c_j = 1)\,1[\phi_j(s) \ne 0]`), so it stays in [0, 1]. :meth:`describe` says where each
    boundary came from.
``indicator`` (default without parametric constraints)
    1 if the state is in any used constraint, else 0: a known feature counts when
    :math:`\phi_j(s) \ne 0` (indicator features), a parametric constraint when :math:`s \in R(\tilde\vartheta)`
    with :math:`\tilde\vartheta` the posterior median of its parameters given :math:`c_m = 1`. Penalty
    magnitudes are often not identified by rankings (only a lower bound is), so this mode does not use them.
``probability``
    :math:`\sum_j P(c_j = 1 \mid \mathcal D)\,\phi_j(s) + \sum_m P(c_m = 1, s \in R(\vartheta_m) \mid \mathcal D)`
    over the features with :math:`P(c_j = 1) \ge` ``threshold`` (default 0.5; a feature the posterior
    leans against would otherwise charge every step it is non-zero): each constraint feature weighted by its
    posterior probability; for a parametric constraint the posterior probability that the state is inside.
``sample``
    At every ``reset`` one kept posterior draw :math:`(c, \vartheta)` is chosen uniformly, with the wrapper's
    own :class:`numpy.random.Generator` (re-seeded by ``reset(seed=...)``); the episode's cost is
    :math:`\sum_j c_j \phi_j(s) + \sum_m c_m 1[s \in R(\vartheta_m)]` under that draw, so that its expectation
    over the posterior is the ``probability`` cost (for indicator features of disjoint regions: 1 inside
    any of the draw's active constraints, else 0).
``penalty``
    :math:`\sum_j -q_j\,\phi_j(s)` with :math:`q_j` the ``quantile`` of :math:`w_{p,j}` given
    :math:`c_j = 1` (reward units; ``quantile=0.05`` gives the larger magnitude, since :math:`w_p \le 0`),
    parametric locations at their posterior median.

``fold_into_reward`` (a coefficient :math:`\kappa`; ``True`` is 1) also returns :math:`r - \kappa c_t` as the
reward; ``info["reward_without_cost"]`` keeps the environment's reward.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

try:
    import gymnasium as gym
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError('pbicrl.envs.inferred_cost needs gymnasium: pip install "pbicrl[envs]"') from exc

from pbicrl.inference.constraints import Constraint, ConstraintError, constraint_from_dict

__all__ = ["MODES", "InferredConstraintCost", "StepFunction", "default_step_functions"]

MODES: tuple[str, ...] = ("conservative", "indicator", "probability", "sample", "penalty")

StepFunction = Callable[[Any, dict], ArrayLike]
"""``f(obs, info) -> array``: per-step features ``(d,)`` or state ``(k,)`` of the state a step reached."""


# ---------------------------------------------------------------------------------------------- env defaults
def _info_array(key: str, what: str) -> StepFunction:
    def read(obs: Any, info: dict) -> NDArray[np.float64]:
        if key not in info:
            raise ValueError(f"{what}: the environment's info has no {key!r} after this step; pass {what}= "
                             f"(a function (obs, info) -> array) for this environment")
        return np.asarray(info[key], dtype=np.float64).reshape(-1)

    read.__name__ = f"info_{key}"
    return read


def _wrapper_chain(env: Any) -> list[Any]:
    chain, e = [], env
    while e is not None and len(chain) < 100:
        chain.append(e)
        e = getattr(e, "env", None)
    return chain


_ICRL_CLASSES = ("BlockedHalfCheetahEnv", "BlockedAntEnv", "BiasedPendulumEnv", "BlockedWalkerEnv", "BlockedSwimmerEnv")


def default_step_functions(env: Any) -> tuple[str, tuple[str, ...], StepFunction, StepFunction, int] | None:
    r"""Per-step features and state of a shipped environment.

    Parameters
    ----------
    env : gymnasium.Env
        Possibly wrapped.

    Returns
    -------
    (name, feature_names, features, state, state_width) or None
        ``None`` for an environment pbicrl does not ship. Point mass and Fetch-Reach: ``info["features"]``
        and the position (:math:`s \in \mathbb R^2`, :math:`\mathbb R^3`); HalfCheetah/Ant with a wall:
        ``info["features"]`` and ``[info["x_position"]]`` (the x reached by the step); the ICRL benchmark's
        tasks (:mod:`pbicrl.envs.icrl_benchmark`): ``info["features"]`` (the reward's terms) and
        ``[info["x_position"]]`` (the post-step ``qpos[0]``, the benchmark's ``obs[0]``); 3x3 grid:
        ``info["features"]`` and ``(row, col)`` of the cell. These are the ``states`` the shipped datasets
        hold, so the ``dims`` of a run's parametric constraints index them.
    """
    feats = _info_array("features", "features")
    for e in _wrapper_chain(env):
        if type(e).__name__ == "WallPenaltyWrapper":
            from pbicrl.envs.mujoco_wall import FEATURE_NAMES, WallPenaltyWrapper

            if isinstance(e, WallPenaltyWrapper):
                x = _info_array("x_position", "state")
                return "wall", tuple(FEATURE_NAMES), feats, x, 1
    u = getattr(env, "unwrapped", env)
    cls = type(u).__name__
    if cls in _ICRL_CLASSES:
        from pbicrl.envs.icrl_benchmark import ICRLTask

        task = getattr(u, "task", None)
        if isinstance(task, ICRLTask):
            return task.name, tuple(task.feature_names), feats, _info_array("x_position", "state"), 1
    if cls in ("PointMassEnv", "FetchReachConstrainedEnv"):
        from pbicrl.envs.regions import FEATURE_NAMES as NAV

        def position(obs: Any, info: dict, u: Any = u) -> NDArray[np.float64]:
            return np.asarray(u.position, dtype=np.float64)  # float64: the observation is float32

        return ("point_mass" if cls == "PointMassEnv" else "fetch_reach"), tuple(NAV), feats, position, \
            (2 if cls == "PointMassEnv" else 3)
    if cls == "GridEnv":
        from pbicrl.envs.grid import GRID_FEATURE_NAMES

        def cell(obs: Any, info: dict) -> NDArray[np.float64]:
            i = int(obs)
            return np.array([i // 3, i % 3], dtype=np.float64)

        return "grid", tuple(GRID_FEATURE_NAMES), feats, cell, 2
    return None


def _good_demonstration_states(post: Any) -> tuple[NDArray[np.float64] | None, str]:
    """States of the best-ranked group of the run's own dataset, and where they came from (or why not)."""
    path = getattr(post, "data_path", None)
    if path is None:
        return None, "the run records no dataset"
    path = Path(path)
    if not path.is_file():
        return None, f"the run's dataset {path} is not there"
    from pbicrl.inference.data import load_dataset

    try:
        ds = load_dataset(path, allow_unlabelled=True)
    except (ValueError, OSError, KeyError) as exc:
        return None, f"the run's dataset {path} cannot be read ({type(exc).__name__})"
    if ds.states is None:
        return None, f"the run's dataset {path} has no states"
    labels = np.asarray(ds.group)
    ranked = labels[labels > 0]
    if ranked.size == 0:
        return None, f"the run's dataset {path} has no labelled trajectories"
    best = int(ranked.min())
    off = np.asarray(ds.offsets)
    rows = np.concatenate([np.arange(off[i], off[i + 1]) for i in np.flatnonzero(labels == best)])
    return np.asarray(ds.states, dtype=np.float64)[rows], f"the good demonstrations (group {best} of {path})"


# ---------------------------------------------------------------------------------------------- geometry
def _inside_many(c: Constraint, s: NDArray[np.float64], thetas: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Whether one state ``s`` (k,) is inside ``c``'s region for each row of ``thetas`` (N, P)."""
    x = s[list(c.dims)]
    D = len(c.dims)
    fam = c.family
    if fam == "axis_halfspace":
        return x[0] >= thetas[:, 0] if getattr(c, "direction", ">=") == ">=" else x[0] <= thetas[:, 0]
    if fam == "box":
        return np.all((x >= thetas[:, :D]) & (x <= thetas[:, D:2 * D]), axis=1)
    if fam == "ball":
        return np.sum((x - thetas[:, :D]) ** 2, axis=1) < thetas[:, D] ** 2
    if fam == "halfspace":
        ang = thetas[:, :D - 1]
        # n_k = sin(a_1)...sin(a_{k-1}) cos(a_k), n_D = sin(a_1)...sin(a_{D-1}) (Halfspace.normal, vectorised)
        sines = np.concatenate([np.ones((len(thetas), 1)), np.cumprod(np.sin(ang), axis=1)], axis=1)
        normals = sines * np.concatenate([np.cos(ang), np.ones((len(thetas), 1))], axis=1)
        return normals @ x >= thetas[:, D - 1]
    raise ConstraintError(f"constraint {c.name!r}: unknown family {fam!r}")  # pragma: no cover


def _inside_rows(c: Constraint, states: NDArray[np.float64], theta: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Membership of each state row for one parameter vector (NaN parameters: outside)."""
    if not np.all(np.isfinite(theta)):
        return np.zeros(len(states), dtype=bool)
    return np.asarray(c.inside(states, theta), dtype=bool)


# ---------------------------------------------------------------------------------------------- the wrapper
class InferredConstraintCost(gym.Wrapper):
    r"""Add ``info["cost"]``, the cost of an inferred constraint, to every step of ``env``.

    Parameters
    ----------
    env : gymnasium.Env
        The environment (its reward is left as it is unless ``fold_into_reward``).
    posterior : Posterior, RunRecord or path
        Draws of :math:`c, w_p` (and :math:`\vartheta`): a :class:`pbicrl.inference.posterior.Posterior`, a
        :class:`pbicrl.io.runs.RunRecord` or a run directory (read with :func:`pbicrl.io.runs.read_run`).
        Parametric constraints are rebuilt from ``settings["constraints"]`` (written by ``pbicrl infer``).
    features : callable, optional
        ``features(obs, info) -> (d,)``, the :math:`d` known features of the reached state, in the
        posterior's order. Default: the environment's own (:func:`default_step_functions`).
    state : callable, optional
        ``state(obs, info) -> (k,)``, the state that parametric constraints' ``dims`` index. Default: the
        environment's own.
    mode : {"conservative", "indicator", "probability", "sample", "penalty"}, optional
        See the module docstring. Default: ``conservative`` if the posterior has parametric constraints, else
        ``indicator``.
    constraints : sequence of str, optional
        Names of the features / parametric constraints to cost. Default: the selected set
        (:math:`P(c_j = 1) > 0.5`) for ``conservative``, ``indicator`` and ``penalty``; the features with
        :math:`P(c_j = 1) \ge` ``threshold`` for ``probability``; every feature with :math:`P(c_j = 1) > 0`
        for ``sample``.
    threshold : float
        ``probability`` mode: the least :math:`P(c_j = 1)` of a costed feature (default 0.5), in (0, 1].
    safe_states : array-like (n, k), "auto" or None
        ``conservative`` mode: states reached by the good (group-1) demonstrations; a wall
        (``axis_halfspace``) boundary is put just beyond the furthest of them. ``"auto"`` (default): the states
        of the best group of the run's dataset when the run records one that can be read, else none. None: the
        posterior's draws only.
    quantile : float
        ``penalty`` mode: quantile of :math:`w_{p,j} \mid c_j = 1` (default 0.5, the median).
    fold_into_reward : bool or float
        Coefficient :math:`\kappa \ge 0` of the cost subtracted from the reward (``False``: 0, ``True``: 1).
    seed : int, optional
        Seed of the ``sample`` mode's generator until ``reset(seed=...)`` re-seeds it.

    Raises
    ------
    ValueError
        Unknown mode, a constraint the posterior does not have or never activates, an empty selected set,
        a parametric constraint without its definition, or an environment without the needed per-step
        features or state (the message names the argument). A feature or state function of the wrong width
        is reported at the first step.

    Notes
    -----
    ``info["cost"]`` is a float on every ``step`` (not on ``reset``, as in Safety-Gymnasium).
    """

    def __init__(self, env: gym.Env, posterior: Any, features: StepFunction | None = None, *,
                 state: StepFunction | None = None, mode: str | None = None,
                 constraints: Sequence[str] | None = None, quantile: float = 0.5,
                 fold_into_reward: bool | float = False, seed: int | None = None, threshold: float = 0.5,
                 safe_states: ArrayLike | str | None = "auto") -> None:
        super().__init__(env)
        if mode is not None and mode not in MODES:
            raise ValueError(f"mode: expected one of {', '.join(MODES)}, got {mode!r}")
        thr = float(threshold)
        if not 0.0 < thr <= 1.0:
            raise ValueError(f"threshold: must be in (0, 1], got {threshold!r}")
        self.threshold = thr
        q = float(quantile)
        if not 0.0 < q < 1.0:
            raise ValueError(f"quantile: must be in (0, 1), got {quantile!r}")
        kappa = float(fold_into_reward)
        if not (math.isfinite(kappa) and kappa >= 0):
            raise ValueError(f"fold_into_reward: must be a bool or a finite coefficient >= 0, got {fold_into_reward!r}")
        if isinstance(posterior, (str, os.PathLike)):
            from pbicrl.io.runs import read_run

            posterior = read_run(posterior)
        self.mode, self.quantile, self.fold_coefficient = mode, q, kappa
        self.posterior = posterior
        self._setup_posterior(posterior, constraints)
        self._setup_conservative(safe_states)
        self._setup_step_functions(env, features, state)
        self._rng = np.random.default_rng(None if seed is None else self._seed_sequence(int(seed)))
        self._draw: int | None = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_run(cls, env: gym.Env, run_dir: str | os.PathLike[str], **kwargs: Any) -> InferredConstraintCost:
        """Wrap ``env`` with the posterior of the run directory ``run_dir`` (``pbicrl infer --out``).

        The shipped environments supply their own per-step features and state; ``kwargs`` go to the
        constructor (``mode``, ``constraints``, ``quantile``, ``fold_into_reward``, ``seed``, ``features``,
        ``state``).
        """
        from pbicrl.io.runs import read_run

        return cls(env, read_run(run_dir), **kwargs)

    def _setup_posterior(self, post: Any, names: Sequence[str] | None) -> None:
        for attr in ("indicators", "penalty_weights", "feature_names"):
            if not hasattr(post, attr):
                raise ValueError(f"posterior: expected a Posterior, a RunRecord or a run directory, got "
                                 f"{type(post).__name__} (no {attr!r})")
        fnames = tuple(str(n) for n in post.feature_names)
        d = len(fnames)
        ind = np.asarray(post.indicators).reshape(-1, d).astype(bool)
        wp = np.asarray(post.penalty_weights, dtype=np.float64).reshape(-1, d)
        if ind.shape[0] == 0:
            raise ValueError("posterior: has no kept draws")
        specs = (getattr(post, "settings", None) or {}).get("constraints") or []
        if self.mode is None:  # safe by construction where the posterior locates a region
            self.mode = "conservative" if specs else "indicator"
        pnames = tuple(getattr(post, "parameter_names", ()) or ())
        if pnames and not specs:
            raise ValueError("posterior: has parameters " + ", ".join(pnames) + " but no definition of its parametric "
                             "constraints (settings['constraints'], written by pbicrl infer)")
        cons: list[Constraint] = []
        for spec in specs:
            clean = {k: v for k, v in dict(spec).items() if k in ("family", "dims", "name", "bounds", "direction")}
            try:
                cons.append(constraint_from_dict(clean))
            except (ConstraintError, TypeError) as exc:
                raise ValueError(f"posterior: settings['constraints'] entry {spec!r} is not a constraint ({exc})") from None
        M = len(cons)
        d_known = d - M
        if d_known < 0 or tuple(c.name for c in cons) != fnames[d_known:]:
            raise ValueError(f"posterior: its parametric constraints {[c.name for c in cons]} are not the last "
                             f"features {list(fnames)}")
        params = getattr(post, "parameters", None)
        P = sum(c.n_params for c in cons)
        theta = np.zeros((ind.shape[0], 0)) if P == 0 else np.asarray(params, dtype=np.float64).reshape(ind.shape[0], -1)
        if theta.shape[1] != P:
            raise ValueError(f"posterior: {theta.shape[1]} parameters per draw, its constraints have {P}")
        offs = np.concatenate([[0], np.cumsum([c.n_params for c in cons])]).astype(int)
        p_on = ind.mean(axis=0)
        if names is None:
            if self.mode == "sample":
                use = [j for j in range(d) if p_on[j] > 0]
                why = "ever active (P(c=1) = 0 for all of "
            elif self.mode == "probability":
                use = [j for j in range(d) if p_on[j] >= self.threshold]
                why = f"likely enough (P(c=1) < threshold {self.threshold:g} for all of "
            else:
                use = [j for j in range(d) if p_on[j] > 0.5]
                why = "selected (P(c=1) > 0.5 for none of "
            if not use:
                raise ValueError("posterior: no constraint is " + why + ", ".join(fnames) + "), so the cost would be 0 "
                                 "everywhere; name the ones to cost with constraints=[...]"
                                 + ("" if self.mode == "sample" else " or use mode='sample'"))
        else:
            if isinstance(names, str):
                names = [names]
            unknown = [n for n in names if n not in fnames]
            if unknown:
                raise ValueError(f"constraints: {', '.join(map(repr, unknown))} not in the posterior (its features and "
                                 f"constraints: {', '.join(fnames)})")
            use = sorted({fnames.index(n) for n in names})
            if not use:
                raise ValueError("constraints: empty; name at least one feature or constraint to cost")
            never = [fnames[j] for j in use if p_on[j] == 0]
            if never:
                raise ValueError(f"constraints: {', '.join(map(repr, never))} never active in the posterior's draws "
                                 "(P(c=1) = 0): no location or penalty to cost")
        self.feature_names = fnames
        self.d_known = d_known
        self.used = tuple(use)
        self.used_known = tuple(j for j in use if j < d_known)
        self.used_param = tuple(j - d_known for j in use if j >= d_known)
        self._cons = cons
        self._ind = ind
        self._theta = [theta[:, offs[m]:offs[m + 1]] for m in range(M)]
        self.p_constraint = p_on
        # point summaries: parameter medians and penalty quantiles given c = 1
        self.location: dict[str, NDArray[np.float64]] = {}
        self.penalty: dict[str, float] = {}
        for j in use:
            on = ind[:, j]
            if j >= d_known:
                th = self._theta[j - d_known][on]
                th = th[np.all(np.isfinite(th), axis=1)]
                if th.shape[0] == 0:
                    raise ValueError(f"posterior: constraint {fnames[j]!r} has no finite parameters in its active draws")
                self.location[fnames[j]] = np.median(th, axis=0)
            if self.mode == "penalty":
                w = wp[on, j]
                w = w[np.isfinite(w)]
                qv = float(np.quantile(w, self.quantile)) if w.size else math.nan
                if not qv <= 0:
                    raise ValueError(f"mode 'penalty': the {self.quantile:g}-quantile of {fnames[j]!r}'s penalty given "
                                     f"c=1 is {qv:g}, not a penalty (<= 0); use mode='indicator'")
                self.penalty[fnames[j]] = qv

    def _setup_conservative(self, safe_states: ArrayLike | str | None) -> None:
        """``conservative`` mode: the boundary of each used wall (``axis_halfspace``) at the edge of its identified
        region nearest the safe side (just beyond the good demonstrations' states when they are known)."""
        self.conservative_location: dict[str, NDArray[np.float64]] = {}
        self.boundary_source: dict[str, str] = {}
        source = "the posterior's draws (the lowest / highest threshold with c = 1)"
        if isinstance(safe_states, str):
            if safe_states != "auto":
                raise ValueError(f"safe_states: expected an (n, k) array, 'auto' or None, got {safe_states!r}")
            safe_states = None
            if self.mode == "conservative" and any(self._cons[m].family == "axis_halfspace" for m in self.used_param):
                safe_states, why = _good_demonstration_states(self.posterior)
                source = why if safe_states is not None else f"{source}; {why}"
        elif safe_states is not None:
            source = "safe_states (given)"
        if safe_states is not None and self.mode != "conservative":
            raise ValueError(f"safe_states: used only by mode 'conservative', not {self.mode!r}")
        safe = None
        if safe_states is not None:
            safe = np.asarray(safe_states, dtype=np.float64)
            if safe.ndim == 1:
                safe = safe[:, None]
            if safe.ndim != 2 or safe.shape[0] == 0 or not np.all(np.isfinite(safe)):
                raise ValueError(f"safe_states: expected a non-empty finite (n, k) array, got shape {np.shape(safe_states)}")
        if self.mode != "conservative":
            return
        for m in self.used_param:
            c = self._cons[m]
            if c.family != "axis_halfspace":
                continue
            j = self.d_known + m
            th = self._theta[m][self._ind[:, j], 0]
            th = th[np.isfinite(th)]
            above = getattr(c, "direction", ">=") == ">="
            edge = float(th.min() if above else th.max())
            if safe is not None:
                k = c.dims[0]
                if k >= safe.shape[1]:
                    raise ValueError(f"safe_states: {safe.shape[1]} column(s); constraint {c.name!r} uses column {k}")
                reach = float(safe[:, k].max() if above else safe[:, k].min())
                edge = float(np.nextafter(reach, math.inf if above else -math.inf))
            self.conservative_location[c.name] = np.array([edge])
            self.boundary_source[c.name] = source

    def _setup_step_functions(self, env: gym.Env, features: StepFunction | None, state: StepFunction | None) -> None:
        need_f = bool(self.used_known)
        need_s = bool(self.used_param)
        default = default_step_functions(env) if (need_f and features is None) or (need_s and state is None) else None
        if default is not None:
            name, env_names, f0, s0, width = default
            # the known features name the environment a run was inferred for, even when only its parametric
            # constraints are costed (a wall run on the point mass would otherwise cost x >= theta on its x)
            if tuple(env_names) != self.feature_names[:self.d_known]:
                raise ValueError(f"env: the {name} environment's features ({', '.join(env_names)}) are not the "
                                 f"posterior's ({', '.join(self.feature_names[:self.d_known])}); wrap the environment the "
                                 "run was inferred for, or pass features=")
            if need_s and state is None:
                bad = [c.name for m, c in enumerate(self._cons) if m in self.used_param and max(c.dims) >= width]
                if bad:
                    raise ValueError(f"env: the {name} environment's state has {width} column(s); constraint(s) "
                                     f"{', '.join(bad)} use column(s) beyond it; pass state=")
            features = features if features is not None else f0
            state = state if state is not None else s0
        if need_f and features is None:
            raise ValueError(f"features: the posterior's constraints {[self.feature_names[j] for j in self.used_known]} "
                             f"are known features, and {type(env.unwrapped).__name__} is not a shipped environment; pass "
                             f"features=(a function (obs, info) -> the {self.d_known} features of the reached state)")
        if need_s and state is None:
            names = [self._cons[m].name for m in self.used_param]
            raise ValueError(f"state: the posterior has parametric constraints {names} on state column(s) "
                             f"{sorted({k for m in self.used_param for k in self._cons[m].dims})}, and "
                             f"{type(env.unwrapped).__name__} is not a shipped environment; pass state=(a function "
                             "(obs, info) -> the state vector those columns index)")
        for what, fn in (("features", features), ("state", state)):
            if fn is not None and not callable(fn):
                raise ValueError(f"{what}: expected a function (obs, info) -> array, got {type(fn).__name__}")
        self.features_fn = features if need_f else None
        self.state_fn = state if need_s else None

    @staticmethod
    def _seed_sequence(seed: int) -> np.random.SeedSequence:
        # a stream of its own: the environment seeds its np_random with the same integer
        return np.random.SeedSequence(seed, spawn_key=(0x1C05,))

    # ------------------------------------------------------------------ cost
    def _check_features(self, phi: ArrayLike) -> NDArray[np.float64]:
        x = np.asarray(phi, dtype=np.float64)
        if x.ndim == 1:
            x = x[None, :]
        if x.ndim != 2 or x.shape[1] != self.d_known:
            raise ValueError(f"features: the feature function returned shape {np.shape(phi)}, expected ({self.d_known},) "
                             f"per step: the posterior's known features {', '.join(self.feature_names[:self.d_known])}")
        bad = ~np.isfinite(x[:, list(self.used_known)])
        if bad.any():
            j = self.used_known[int(np.argwhere(bad)[0][1])]
            raise ValueError(f"features: non-finite value of {self.feature_names[j]!r}")
        return x

    def _check_states(self, s: ArrayLike) -> NDArray[np.float64]:
        x = np.asarray(s, dtype=np.float64)
        if x.ndim == 1:
            x = x[None, :]
        need = 1 + max(k for m in self.used_param for k in self._cons[m].dims)
        if x.ndim != 2 or x.shape[1] < need:
            raise ValueError(f"state: the state function returned shape {np.shape(s)}, the parametric constraints "
                             f"{[self._cons[m].name for m in self.used_param]} need at least {need} column(s) per step")
        if not np.all(np.isfinite(x)):
            raise ValueError("state: non-finite state value")
        return x

    def costs(self, features: ArrayLike | None = None, states: ArrayLike | None = None, *,
              draw: int | None = None) -> NDArray[np.float64]:
        r"""Cost of ``T`` reached states (the wrapper's mode), shape (T,).

        Parameters
        ----------
        features : array-like (T, d) or (d,), optional
            Known features; needed when a known feature is costed.
        states : array-like (T, k) or (k,), optional
            States; needed when a parametric constraint is costed.
        draw : int, optional
            ``sample`` mode: index of the kept draw (flattened over chains); default the episode's draw.
        """
        if self.used_known and features is None:
            raise ValueError("features: required (the cost uses known features)")
        if self.used_param and states is None:
            raise ValueError("state: required (the cost uses parametric constraints)")
        phi = self._check_features(features) if self.used_known else None
        s = self._check_states(states) if self.used_param else None
        T = (phi if phi is not None else s).shape[0]  # type: ignore[union-attr]
        if self.mode == "sample":
            n = self._draw if draw is None else int(draw)
            if n is None:
                n = self._new_draw()
            if not 0 <= n < self._ind.shape[0]:
                raise ValueError(f"draw: must be in [0, {self._ind.shape[0]}), got {n}")
        out = np.zeros(T)
        for j in self.used_known:
            v = phi[:, j]  # type: ignore[index]
            if self.mode == "indicator":
                out = np.maximum(out, (v != 0).astype(float))
            elif self.mode == "conservative":
                out = np.maximum(out, self.p_constraint[j] * (v != 0))
            elif self.mode == "sample":
                if self._ind[n, j]:
                    out += v
            elif self.mode == "probability":
                out += self.p_constraint[j] * v
            else:
                out += -self.penalty[self.feature_names[j]] * v
        for m in self.used_param:
            c = self._cons[m]
            name = c.name
            j = self.d_known + m
            if self.mode == "probability":
                on = self._ind[:, j]
                th = self._theta[m]
                N = self._ind.shape[0]
                out += np.array([np.count_nonzero(on & _inside_many(c, row, th)) / N for row in s])  # type: ignore[union-attr]
                continue
            if self.mode == "conservative":
                if name in self.conservative_location:
                    inside = _inside_rows(c, s, self.conservative_location[name])  # type: ignore[arg-type]
                else:  # the union of the active draws' regions
                    on = self._ind[:, j]
                    th = self._theta[m][on]
                    th = th[np.all(np.isfinite(th), axis=1)]
                    inside = np.array([bool(_inside_many(c, row, th).any()) for row in s])  # type: ignore[union-attr]
                out = np.maximum(out, self.p_constraint[j] * inside)
                continue
            if self.mode == "sample":
                if not self._ind[n, j]:
                    continue
                inside = _inside_rows(c, s, self._theta[m][n])  # type: ignore[arg-type]
            else:
                inside = _inside_rows(c, s, self.location[name])  # type: ignore[arg-type]
            if self.mode == "penalty":
                out += -self.penalty[name] * inside
            elif self.mode == "sample":
                out += inside
            else:
                out = np.maximum(out, inside.astype(float))
        return out

    def _new_draw(self) -> int:
        self._draw = int(self._rng.integers(self._ind.shape[0]))
        return self._draw

    @property
    def draw(self) -> int | None:
        """``sample`` mode: index of this episode's posterior draw (``None`` before the first reset)."""
        return self._draw

    def describe(self) -> dict[str, Any]:
        """JSON-ready description of the cost: mode, and per costed constraint its kind, :math:`P(c=1)`,
        median location (parametric) and penalty quantile (``penalty`` mode)."""
        terms = []
        for j in self.used:
            name = self.feature_names[j]
            t: dict[str, Any] = {"name": name, "kind": "parametric" if j >= self.d_known else "feature",
                                 "p_constraint": float(self.p_constraint[j])}
            if j >= self.d_known:
                c = self._cons[j - self.d_known]
                t["family"] = c.family
                t["dims"] = list(c.dims)
                t["median_location"] = dict(zip(c.param_names(), self.location[name].tolist()))
                if name in self.conservative_location:
                    t["conservative_location"] = dict(zip(c.param_names(), self.conservative_location[name].tolist()))
                    t["boundary_from"] = self.boundary_source[name]
                elif self.mode == "conservative":
                    t["conservative_region"] = "union of the active draws' regions"
            if name in self.penalty:
                t["penalty_quantile"] = self.penalty[name]
            terms.append(t)
        return {"mode": self.mode, "quantile": self.quantile if self.mode == "penalty" else None,
                **({"threshold": self.threshold} if self.mode == "probability" else {}),
                "fold_into_reward": self.fold_coefficient, "terms": terms}

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset ``env``; ``seed`` also re-seeds the ``sample`` mode's generator, which then draws this
        episode's posterior sample."""
        if seed is not None:
            self._rng = np.random.default_rng(self._seed_sequence(int(seed)))
        obs, info = self.env.reset(seed=seed, options=options)
        if self.mode == "sample":
            self._new_draw()
        return obs, info

    def step(self, action: Any):
        """Step ``env`` and add ``info["cost"]`` (and fold it into the reward if asked)."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        phi = self.features_fn(obs, info) if self.features_fn is not None else None
        s = self.state_fn(obs, info) if self.state_fn is not None else None
        cost = float(self.costs(phi, s)[0])
        info = dict(info)
        info["cost"] = cost
        if self.fold_coefficient:
            info["reward_without_cost"] = reward
            reward = float(reward) - self.fold_coefficient * cost
        return obs, reward, terminated, truncated, info
