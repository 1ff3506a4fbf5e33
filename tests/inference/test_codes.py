"""The named integer codes (:mod:`pbicrl.inference.codes`): unique per family, and Python and the compiled loop agree."""

from __future__ import annotations

import numpy as np
import pytest

from pbicrl.inference import codes
from pbicrl.inference.constraints import FAMILIES, AxisHalfspace, Ball, Box, ConstraintSet, Halfspace
from pbicrl.inference.data import Dataset
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.priors import WeightPrior
from pbicrl.inference.samplers import build_kernel
from pbicrl.inference.samplers.kernels import METHODS
from pbicrl.inference.synthetic import make_problem

PREFIXES = ("MODE_", "MOVE_", "C_", "PRIOR_", "FAM_", "LIK_")


def _family(prefix: str) -> dict[str, int]:
    """The codes of one family (the name tables beside them, e.g. ``MOVE_NAMES``, are dicts or tuples)."""
    return {k: v for k, v in vars(codes).items()
            if k.startswith(prefix) and k.isupper() and not isinstance(v, (dict, tuple)) and k != "N_COUNTS"}


@pytest.mark.parametrize("prefix", PREFIXES)
def test_codes_are_unique_plain_ints_numbered_from_zero(prefix):
    fam = _family(prefix)
    assert len(fam) >= 3
    assert all(type(v) is int for v in fam.values())  # plain ints: what Numba freezes as constants
    assert sorted(fam.values()) == list(range(len(fam))), fam
    assert set(fam) <= set(codes.__all__)


def test_name_tables_match_the_constants():
    assert codes.MODES == {"pbicrl": codes.MODE_PBICRL, "paper": codes.MODE_PAPER, "bpl": codes.MODE_BPL,
                           "authors": codes.MODE_AUTHORS}
    assert set(codes.MODES) == set(METHODS)
    assert sorted(codes.MOVE_NAMES) == sorted(_family("MOVE_").values())
    assert codes.MOVES[codes.MOVE_WEIGHT] == codes.MOVE_NAMES[codes.MOVE_JOINT] == "weight"
    assert len(codes.COUNTERS) == len(set(codes.COUNTERS)) == codes.N_COUNTS
    for table, prefix in ((codes.PRIOR_KINDS, "PRIOR_"), (codes.FAMILY_CODES, "FAM_"), (codes.LIKELIHOODS, "LIK_")):
        assert sorted(table.values()) == sorted(_family(prefix).values())


def test_python_side_uses_the_codes():
    from pbicrl.analysis import export
    from pbicrl.inference import likelihood_kernels as lk
    from pbicrl.inference.samplers import _mcmc, _priorkern, driver

    assert FAMILIES == tuple(codes.FAMILY_CODES)
    for kind, code in codes.PRIOR_KINDS.items():
        assert WeightPrior(kind, -5.0, 5.0).code == code if kind == "flat" else WeightPrior(kind).code == code
    # each code has one name: no second name for a code or a table of codes in the modules that use them
    for module in (export, lk, _mcmc, _priorkern, driver):
        aliases = [k for k in vars(module) if k.startswith(("KIND_", "MOVE_CODES", "run_chunk"))]
        assert not aliases, f"{module.__name__}: {aliases}"


def test_compiled_prior_density_branches_on_the_prior_codes():
    from pbicrl.inference.samplers._priorkern import logprior_w

    prm = np.array([[-10.0, 0.0, 0.0, 2.0, 3.0, 0.25]])  # low, high, loc, scale, df, log_norm
    assert logprior_w(codes.PRIOR_IMPROPER, prm, 0, -1.0) == 0.0
    assert logprior_w(codes.PRIOR_FLAT, prm, 0, -1.0) == -0.25
    assert logprior_w(codes.PRIOR_NORMAL, prm, 0, -1.0) == -0.5 * 0.25 - 0.25
    assert logprior_w(codes.PRIOR_STUDENT_T, prm, 0, -1.0) == pytest.approx(-2.0 * np.log1p(0.25 / 3.0) - 0.25)


def test_compiled_constraint_columns_branch_on_the_family_codes():
    """Every family's compiled column (by its code) equals the Python region test of the family by that name."""
    from pbicrl.inference.samplers._parametric import param_column

    rng = np.random.default_rng(0)
    lengths = rng.integers(5, 15, 12)
    states = [rng.uniform(-2, 2, (n, 2)) for n in lengths]
    ds = Dataset.from_trajectories([np.zeros((n, 1)) for n in lengths], np.repeat([1, 2], 6), states=states)
    cs = ConstraintSet((AxisHalfspace(0, direction="<=", name="a"), Halfspace((0, 1), name="h"),
                        Box((0, 1), name="b"), Ball((0, 1), name="c")), ds)
    A = cs.compiled_arrays()
    assert [codes.FAMILY_CODES[c.family] for c in cs.constraints] == A["fam"].tolist() == [
        codes.FAM_AXIS, codes.FAM_HALFSPACE, codes.FAM_BOX, codes.FAM_BALL]
    theta = np.array([0.3, 0.7, 0.2, -1.0, -0.5, 1.0, 0.8, 0.1, -0.2, 1.1])
    assert theta.size == cs.n_params
    for m in range(cs.n_constraints):
        for naive in (False, True):
            col = np.empty(ds.n_trajectories)
            param_column(m, theta, 1.0, A["fam"], A["sign"], A["poff"], A["dims_off"], A["dims"], A["sorted_vals"],
                         A["states"], A["offsets"], A["inv_len"], col, naive)
            np.testing.assert_allclose(col, cs.mean_feature(m, cs.theta_of(theta, m)), rtol=1e-12,
                                       err_msg=f"{cs.constraints[m].family}")


def test_compiled_loop_counts_moves_under_the_counter_codes():
    """Paper mode with f_s = n + 1 flips at every iteration: only the flip counters and evaluations move."""
    lik = PreferenceLikelihood.from_dataset(make_problem(10, seed=1).dataset)
    n = 200
    kernel = build_kernel(lik, method="paper", n_iterations=n, f_s=n + 1)
    end = kernel.run(np.random.default_rng(0), kernel.init(0), n)
    c = end.counts
    assert c.shape == (codes.N_COUNTS,)
    assert c[codes.C_FLIP_PROP] == n and 0 < c[codes.C_FLIP_ACC] < n and c[codes.C_EVALS] > 0
    assert c[codes.C_W_PROP] == c[codes.C_W_ACC] == c[codes.C_T_PROP] == c[codes.C_T_ACC] == 0
    bpl = build_kernel(lik, method="bpl", n_iterations=n, weight_prior=WeightPrior("flat", -50, 50))
    c = bpl.run(np.random.default_rng(0), bpl.init(0), n).counts
    assert c[codes.C_W_PROP] == n and c[codes.C_FLIP_PROP] == 0 and 0 < c[codes.C_W_ACC] < n
