"""Parametric constraint features :math:`\\phi_\\vartheta(s)` (paper Section IV-B, Algorithm 2).

Each constraint is the indicator of a region of state space whose location :math:`\\vartheta` is unknown:

================== ======================================= =========================================
family             region (``s`` = the selected state dims)  parameters :math:`\\vartheta`
================== ======================================= =========================================
``axis_halfspace`` :math:`s_k \\ge \\vartheta` (or ``<=``)     ``threshold``
``halfspace``      :math:`n(\\alpha)^\\top s \\ge b`            ``angle`` (2-D; ``angle1..`` in n-D), ``offset``
``box``            :math:`l \\le s \\le u` (closed)            ``lower0..``, ``upper0..``
``ball``           :math:`\\lVert s - o \\rVert < \\rho`        ``centre0..``, ``radius``
================== ======================================= =========================================

The feature of trajectory :math:`\\tau_i` is the fraction of its states inside the region. A proposal of
:math:`\\vartheta` recomputes that fraction for every trajectory:

* axis halfspace - each trajectory's coordinate is sorted once; a count is a binary search,
  :math:`O(N \\log T)` per proposal;
* box - when a step moves the bounds of one dimension only the states inside the other dimensions' bounds
  matter, but a joint step moves every bound, so a box proposal checks every state, :math:`O(S\\,D)`;
* ball and general halfspace - :math:`O(S\\,D)` per proposal (the centre or normal changes every distance).

Priors on :math:`\\vartheta` are uniform within bounds; by default the bounds span the data (the range of the
selected state coordinates; radius up to the diagonal of that range).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbicrl.inference.codes import FAMILY_CODES
from pbicrl.inference.data import Dataset

__all__ = ["Constraint", "AxisHalfspace", "Halfspace", "Box", "Ball", "ConstraintError", "ConstraintSet",
           "constraint_from_dict", "constraint_set_of", "FAMILIES"]

FAMILIES = tuple(FAMILY_CODES)  # the codes themselves live in pbicrl.inference.codes


class ConstraintError(ValueError):
    """Invalid constraint declaration; the message names the constraint and the field."""


@dataclass(frozen=True)
class Constraint:
    """Base class: a parametric region over the state columns ``dims``.

    Parameters
    ----------
    dims : tuple of int
        State columns the region is defined on.
    name : str
        Used for the feature and parameter names.
    bounds : sequence of (low, high) or None
        Uniform prior bounds per parameter (in :meth:`param_names` order); ``None``: from the data.
    """

    dims: tuple[int, ...]
    name: str = ""
    bounds: tuple[tuple[float, float], ...] | None = None

    family: str = field(default="", init=False)
    _family: ClassVar[str] = ""  # each family's class sets it; ``family`` is set from it on construction

    def __post_init__(self) -> None:
        object.__setattr__(self, "family", self._family)
        label = self.name or self.family
        try:
            dims = (self.dims,) if isinstance(self.dims, (int, np.integer)) else tuple(self.dims)
            if len(dims) == 0:
                raise ConstraintError(f"constraint {label!r}: dims is empty")
            if any(isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) for k in dims):
                raise ConstraintError(f"constraint {label!r}: dims must be state column numbers (integers), "
                                      f"got {list(dims)!r}")
        except TypeError:
            raise ConstraintError(f"constraint {label!r}: dims must be a list of state column numbers, "
                                  f"got {self.dims!r}") from None
        object.__setattr__(self, "dims", tuple(int(k) for k in dims))
        if not self.name:
            object.__setattr__(self, "name", f"{self.family}{'_'.join(map(str, self.dims))}")
        if self.bounds is not None:
            try:
                b = tuple((float(lo), float(hi)) for lo, hi in self.bounds)
            except (TypeError, ValueError):
                raise ConstraintError(f"constraint {self.name!r}: bounds must be [low, high] pairs of numbers, "
                                      f"got {self.bounds!r}") from None
            if len(b) != self.n_params:
                raise ConstraintError(f"constraint {self.name!r}: bounds has {len(b)} pairs, the family "
                                      f"{self.family} has {self.n_params} parameters {self.param_names()}")
            for (lo, hi), pn in zip(b, self.param_names()):
                if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                    raise ConstraintError(f"constraint {self.name!r}: bounds of {pn} must be finite with low < high, got [{lo}, {hi}]")
            object.__setattr__(self, "bounds", b)

    @property
    def n_params(self) -> int:
        raise NotImplementedError

    def param_names(self) -> list[str]:
        raise NotImplementedError

    def default_bounds(self, states: NDArray[np.float64]) -> list[tuple[float, float]]:
        raise NotImplementedError

    def inside(self, states: NDArray[np.float64], theta: ArrayLike) -> NDArray[np.bool_]:
        """Reference (NumPy) membership of each state row; the compiled kernel must agree."""
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:
        return {"family": self.family, "dims": list(self.dims), "name": self.name,
                "bounds": None if self.bounds is None else [list(b) for b in self.bounds]}


def _span(states: NDArray, dims: Sequence[int]) -> tuple[NDArray, NDArray]:
    x = states[:, list(dims)]
    lo, hi = x.min(axis=0), x.max(axis=0)
    pad = np.where(hi > lo, 0.0, 1.0)
    return lo - pad, hi + pad


@dataclass(frozen=True)
class AxisHalfspace(Constraint):
    """:math:`s_k \\ge \\vartheta` (``direction=">="``) or :math:`s_k \\le \\vartheta` - e.g. a wall at x = 8."""

    direction: Literal[">=", "<="] = ">="
    _family: ClassVar[str] = "axis_halfspace"

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.dims) != 1:
            raise ConstraintError(f"constraint {self.name!r}: an axis halfspace takes one state dimension, got {list(self.dims)}")
        if self.direction not in (">=", "<="):
            raise ConstraintError(f"constraint {self.name!r}: direction must be '>=' or '<=', got {self.direction!r}")

    @property
    def n_params(self) -> int:
        return 1

    def param_names(self) -> list[str]:
        return ["threshold"]

    def default_bounds(self, states: NDArray[np.float64]) -> list[tuple[float, float]]:
        lo, hi = _span(states, self.dims)
        return [(float(lo[0]), float(hi[0]))]

    def inside(self, states: NDArray[np.float64], theta: ArrayLike) -> NDArray[np.bool_]:
        x = states[:, self.dims[0]]
        t = float(np.asarray(theta).reshape(-1)[0])
        return x >= t if self.direction == ">=" else x <= t

    def to_dict(self) -> dict[str, Any]:
        return super().to_dict() | {"direction": self.direction}


@dataclass(frozen=True)
class Halfspace(Constraint):
    """:math:`n^\\top s \\ge b` with unit normal :math:`n` from spherical angles (``angle`` in 2-D)."""

    _family: ClassVar[str] = "halfspace"

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.dims) < 2:
            raise ConstraintError(f"constraint {self.name!r}: a general halfspace needs >= 2 dims; use axis_halfspace for one")

    @property
    def n_params(self) -> int:
        return len(self.dims)

    def param_names(self) -> list[str]:
        D = len(self.dims)
        return (["angle"] if D == 2 else [f"angle{k + 1}" for k in range(D - 1)]) + ["offset"]

    def default_bounds(self, states: NDArray[np.float64]) -> list[tuple[float, float]]:
        lo, hi = _span(states, self.dims)
        r = float(np.linalg.norm(np.maximum(np.abs(lo), np.abs(hi))))
        D = len(self.dims)
        ang = [(0.0, math.pi)] * (D - 2) + [(-math.pi, math.pi)]
        return ang + [(-r, r)]

    @staticmethod
    def normal(angles: ArrayLike) -> NDArray[np.float64]:
        r"""Unit normal from hyperspherical angles: :math:`n_1 = \cos a_1`, :math:`n_2 = \sin a_1 \cos a_2`, ..."""
        a = np.asarray(angles, dtype=np.float64).reshape(-1)
        D = a.size + 1
        n = np.empty(D)
        s = 1.0
        for k in range(D - 1):
            n[k] = s * math.cos(a[k])
            s *= math.sin(a[k])
        n[D - 1] = s
        return n

    def inside(self, states: NDArray[np.float64], theta: ArrayLike) -> NDArray[np.bool_]:
        t = np.asarray(theta, dtype=np.float64).reshape(-1)
        return states[:, list(self.dims)] @ self.normal(t[:-1]) >= t[-1]


@dataclass(frozen=True)
class Box(Constraint):
    """Axis-aligned box :math:`l \\le s \\le u` (closed) - e.g. the Fetch-Reach regions."""

    _family: ClassVar[str] = "box"

    @property
    def n_params(self) -> int:
        return 2 * len(self.dims)

    def param_names(self) -> list[str]:
        return [f"lower{k}" for k in self.dims] + [f"upper{k}" for k in self.dims]

    def default_bounds(self, states: NDArray[np.float64]) -> list[tuple[float, float]]:
        lo, hi = _span(states, self.dims)
        b = [(float(a), float(z)) for a, z in zip(lo, hi)]
        return b + b

    def inside(self, states: NDArray[np.float64], theta: ArrayLike) -> NDArray[np.bool_]:
        t = np.asarray(theta, dtype=np.float64).reshape(-1)
        D = len(self.dims)
        x = states[:, list(self.dims)]
        return np.all((x >= t[:D]) & (x <= t[D:]), axis=1)


@dataclass(frozen=True)
class Ball(Constraint):
    """Open ball :math:`\\lVert s - o \\rVert < \\rho` - e.g. the point-mass discs."""

    _family: ClassVar[str] = "ball"

    @property
    def n_params(self) -> int:
        return len(self.dims) + 1

    def param_names(self) -> list[str]:
        return [f"centre{k}" for k in self.dims] + ["radius"]

    def default_bounds(self, states: NDArray[np.float64]) -> list[tuple[float, float]]:
        lo, hi = _span(states, self.dims)
        diag = float(np.linalg.norm(hi - lo))
        return [(float(a), float(z)) for a, z in zip(lo, hi)] + [(0.0, diag)]

    def inside(self, states: NDArray[np.float64], theta: ArrayLike) -> NDArray[np.bool_]:
        t = np.asarray(theta, dtype=np.float64).reshape(-1)
        D = len(self.dims)
        x = states[:, list(self.dims)]
        return np.sum((x - t[:D]) ** 2, axis=1) < t[D] ** 2


_CLASSES = {"axis_halfspace": AxisHalfspace, "halfspace": Halfspace, "box": Box, "ball": Ball}


def constraint_from_dict(spec: dict[str, Any]) -> Constraint:
    """Build from a TOML/JSON table: ``{family = "axis_halfspace", dims = [0], direction = ">=", bounds = [[0, 20]]}``."""
    spec = dict(spec)
    fam = spec.pop("family", None)
    label = spec.get("name", fam)
    if fam not in _CLASSES:
        raise ConstraintError(f"constraint {label!r}: unknown family {fam!r}; choose one of {', '.join(FAMILIES)}")
    if "dims" not in spec:
        raise ConstraintError(f"constraint {label!r}: 'dims' (state columns) is required")
    allowed = {"dims", "name", "bounds"} | ({"direction"} if fam == "axis_halfspace" else set())
    unknown = set(spec) - allowed
    if unknown:
        raise ConstraintError(f"constraint {label!r}: unknown key(s) {sorted(unknown)} for family {fam}; allowed {sorted(allowed)}")
    if spec.get("bounds") is not None:
        try:
            spec["bounds"] = tuple(tuple(b) for b in spec["bounds"])
        except TypeError:
            raise ConstraintError(f"constraint {label!r}: bounds must be a list of [low, high] pairs, "
                                  f"got {spec['bounds']!r}") from None
    return _CLASSES[fam](**spec)


@dataclass(frozen=True, eq=False)
class ConstraintSet:
    """Parametric constraints bound to a dataset's states, with everything the compiled kernel needs.

    Attributes
    ----------
    constraints : tuple of Constraint
    bounds : ndarray (P, 2)
        Prior bounds of all parameters, concatenated in constraint order.
    param_offsets : ndarray (M+1,)
        Parameters of constraint ``m`` are ``param_offsets[m]:param_offsets[m+1]``.
    """

    constraints: tuple[Constraint, ...]
    dataset: Dataset
    bounds: NDArray[np.float64] = field(init=False)
    param_offsets: NDArray[np.int64] = field(init=False)

    def __post_init__(self) -> None:
        ds = self.dataset
        if ds.states is None:
            raise ConstraintError("constraints: the dataset has no states; parametric constraints are defined on states")
        k = ds.states.shape[1]
        names = set(ds.feature_names)
        seen: set[str] = set()
        b = []
        offs = [0]
        for c in self.constraints:
            if not isinstance(c, Constraint):
                raise ConstraintError(f"constraints: expected Constraint objects, got {type(c).__name__}")
            bad = [d for d in c.dims if not 0 <= d < k]
            if bad:
                raise ConstraintError(f"constraint {c.name!r}: dims {bad} out of range; the states have {k} columns (0..{k - 1})")
            if c.name in names or c.name in seen:
                raise ConstraintError(f"constraint {c.name!r}: name clashes with a feature or another constraint")
            seen.add(c.name)
            cb = list(c.bounds) if c.bounds is not None else c.default_bounds(ds.states)
            b.extend(cb)
            offs.append(offs[-1] + c.n_params)
        if not self.constraints:
            raise ConstraintError("constraints: empty list")
        object.__setattr__(self, "bounds", np.array(b, dtype=np.float64).reshape(-1, 2))
        object.__setattr__(self, "param_offsets", np.array(offs, dtype=np.int64))

    @property
    def n_constraints(self) -> int:
        return len(self.constraints)

    @property
    def n_params(self) -> int:
        return int(self.param_offsets[-1])

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.constraints)

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(f"{c.name}.{p}" for c in self.constraints for p in c.param_names())

    def theta_of(self, theta: NDArray, m: int) -> NDArray:
        return theta[self.param_offsets[m]:self.param_offsets[m + 1]]

    def mean_feature(self, m: int, theta: ArrayLike) -> NDArray[np.float64]:
        """Reference: fraction of each trajectory's states inside constraint ``m``'s region, (N,)."""
        ds = self.dataset
        inside = self.constraints[m].inside(ds.states, theta).astype(np.float64)
        return np.add.reduceat(inside, ds.offsets[:-1]) / ds.lengths

    def compiled_arrays(self) -> dict[str, NDArray]:
        """Flat arrays for :mod:`pbicrl.inference.samplers._mcmc`."""
        ds = self.dataset
        M = self.n_constraints
        fam = np.array([FAMILY_CODES[c.family] for c in self.constraints], dtype=np.int64)
        sign = np.array([(-1 if getattr(c, "direction", ">=") == "<=" else 1) for c in self.constraints], dtype=np.int64)
        dims_off = np.concatenate([[0], np.cumsum([len(c.dims) for c in self.constraints])]).astype(np.int64)
        dims = np.concatenate([np.array(c.dims, dtype=np.int64) for c in self.constraints])
        # Sorted coordinates per trajectory, for binary-search counts (axis halfspaces only).
        sorted_vals = np.zeros((M, ds.states.shape[0]))
        for m, c in enumerate(self.constraints):
            if c.family == "axis_halfspace":
                x = ds.states[:, c.dims[0]]
                for i in range(ds.n_trajectories):
                    a, z = ds.offsets[i], ds.offsets[i + 1]
                    sorted_vals[m, a:z] = np.sort(x[a:z])
        return {"fam": fam, "sign": sign, "poff": self.param_offsets, "dims_off": dims_off, "dims": dims,
                "sorted_vals": sorted_vals, "states": np.ascontiguousarray(ds.states), "offsets": ds.offsets,
                "inv_len": 1.0 / ds.lengths.astype(np.float64), "lo": self.bounds[:, 0].copy(), "hi": self.bounds[:, 1].copy()}

    def to_dict(self) -> list[dict[str, Any]]:
        return [c.to_dict() | {"resolved_bounds": self.bounds[self.param_offsets[m]:self.param_offsets[m + 1]].tolist()}
                for m, c in enumerate(self.constraints)]


def constraint_set_of(run: Any, dataset: Any) -> "ConstraintSet | None":
    """The :class:`ConstraintSet` a run sampled with, rebuilt over ``dataset``, or None.

    ``run`` is a :class:`~pbicrl.inference.posterior.Posterior` or :class:`~pbicrl.io.runs.RunRecord`; its
    ``settings["constraints"]`` hold each constraint's ``to_dict()`` plus ``resolved_bounds``, which record the prior only (the features depend
    on the family, dimensions and direction), so they are left out.
    """
    specs = (dict(getattr(run, "settings", {}) or {})).get("constraints")
    if not specs:
        return None
    return ConstraintSet(tuple(constraint_from_dict({k: v for k, v in spec.items() if k != "resolved_bounds"})
                               for spec in specs), dataset)
