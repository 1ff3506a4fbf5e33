"""Parametric constraints: counts against brute force, recovery of a wall, a ball and a box, bad declarations."""

import numpy as np
import pytest

import pbicrl
from pbicrl.config import ConfigError, load_config
from pbicrl.inference.constraints import AxisHalfspace, Ball, Box, ConstraintError, ConstraintSet, Halfspace, constraint_from_dict
from pbicrl.inference.data import Dataset
from pbicrl.analysis.metrics import cmse_grid, cmse_location, halfspace_indicator, mean_std
from pbicrl.inference.samplers._parametric import param_column
from pbicrl.inference.synthetic import make_region_problem, make_wall_problem


def _grid_data(seed=0):
    rng = np.random.default_rng(seed)
    # values on a 0.5 grid, so thresholds hit ties
    trajs = [np.round(rng.normal(size=(int(rng.integers(1, 30)), 3)) * 2) / 2 for _ in range(25)]
    return Dataset.from_trajectories([np.ones((len(t), 1)) for t in trajs], [1 + i % 2 for i in range(25)], states=trajs)


def test_counts_equal_brute_force_with_ties_both_directions():
    ds = _grid_data()
    cs = ConstraintSet((AxisHalfspace(0, name="ge"), AxisHalfspace(1, direction="<=", name="le"), Box((0, 2), name="box"),
                        Ball((1, 2), name="ball"), Halfspace((0, 1, 2), name="hs"), Halfspace((0, 1), name="hs2")), ds)
    A = cs.compiled_arrays()
    rng = np.random.default_rng(1)
    out = np.empty(ds.n_trajectories)
    for m in range(cs.n_constraints):
        lo, hi = cs.bounds[cs.param_offsets[m]:cs.param_offsets[m + 1]].T
        for _ in range(40):
            th = np.zeros(cs.n_params)
            th[cs.param_offsets[m]:cs.param_offsets[m + 1]] = np.round(rng.uniform(lo, hi) * 2) / 2
            brute = np.array([cs.constraints[m].inside(ds.trajectory_states(i), cs.theta_of(th, m)).mean()
                              for i in range(ds.n_trajectories)])
            for naive in (False, True):
                param_column(m, th, 2.0, A["fam"], A["sign"], A["poff"], A["dims_off"], A["dims"], A["sorted_vals"],
                             A["states"], A["offsets"], A["inv_len"], out, naive)
                np.testing.assert_allclose(out, 2.0 * brute, rtol=0, atol=1e-12)


def test_recovers_wall_location():
    ds = make_wall_problem(50, wall=8.0, seed=0).dataset
    post = pbicrl.infer(ds, constraints=[AxisHalfspace(0, direction=">=", name="wall")], n_iterations=60_000,
                        n_chains=4, seed=0, sigma=1.0, progress=False)
    assert post.p_constraint[-1] > 0.99
    assert abs(post.map_parameters_active[0] - 8.0) < 0.3
    assert post.acceptance_rate()["parameter"] > 0.05  # theta is actually proposed (unlike Algorithm 2 as printed)
    paper = pbicrl.infer(ds, method="paper", f_s=3, sigma=1.0, constraints=[AxisHalfspace(0, name="wall")],
                         n_iterations=60_000, n_chains=2, seed=0, progress=False)
    assert paper.counts[:, 5].sum() > 0 and abs(paper.map_parameters_active[0] - 8.0) < 0.3


@pytest.mark.parametrize("region, constraint", [
    ("ball", Ball((0, 1), name="disc", bounds=((0, 10), (0, 10), (0.5, 5)))),
    ("box", Box((0, 1), name="box", bounds=((0, 10),) * 4)),
])
def test_recovers_ball_and_box(region, constraint):
    prob, truth = make_region_problem(40, region=region, seed=1)
    post = pbicrl.infer(prob.dataset, constraints=[constraint], n_iterations=60_000, n_chains=4, seed=0,
                        sigma_theta=0.3, progress=False)
    assert post.p_constraint[-1] > 0.99
    np.testing.assert_allclose(post.map_parameters_active, truth, atol=0.4)


def test_summary_has_parameters(tmp_path):
    ds = make_wall_problem(10, seed=1).dataset
    post = pbicrl.infer(ds, constraints=[{"family": "axis_halfspace", "dims": [0], "name": "wall"}],
                        n_iterations=3000, n_chains=2, seed=0, progress=False)
    s = post.summary()
    assert set(s["map"]["parameters"]) == {"wall.threshold"}
    assert set(s["posterior"]["parameters"]["wall.threshold"]) >= {"mean", "ci90"}
    post.save(tmp_path / "r")
    z = np.load(tmp_path / "r" / "chains.npz")
    assert z["parameters"].shape == (2, post.n_draws, 1)


@pytest.mark.parametrize("spec, message", [
    ({"family": "cone", "dims": [0]}, "unknown family 'cone'"),
    ({"family": "box"}, "'dims'"),
    ({"family": "axis_halfspace", "dims": [0, 1]}, "one state dimension"),
    ({"family": "axis_halfspace", "dims": [0], "direction": ">"}, "direction must be"),
    ({"family": "box", "dims": [0], "bounds": [[1, 1], [0, 2]]}, "low < high"),
    ({"family": "ball", "dims": [0], "bounds": [[0, 1]]}, "bounds has 1 pairs"),
    ({"family": "box", "dims": [0], "colour": "red"}, "unknown key"),
    ({"family": "halfspace", "dims": [0]}, "needs >= 2 dims"),
])
def test_bad_declarations(spec, message):
    with pytest.raises(ConstraintError, match=message):
        constraint_from_dict(spec)


def test_dims_out_of_range_and_missing_states(tmp_path):
    ds = make_wall_problem(5, seed=0).dataset
    with pytest.raises(ConstraintError, match=r"dims \[3\] out of range"):
        ConstraintSet((AxisHalfspace(3),), ds)
    no_states = Dataset(ds.features, ds.offsets, ds.group)
    with pytest.raises(ConstraintError, match="no states"):
        ConstraintSet((AxisHalfspace(0),), no_states)
    cfg = tmp_path / "c.toml"
    cfg.write_text('[[constraints]]\nfamily = "sphere"\ndims = [0]\n')
    with pytest.raises(ConstraintError, match="unknown family"):
        load_config(cfg)
    cfg.write_text('constraints = 3\n')
    with pytest.raises(ConfigError, match="constraints"):
        load_config(cfg)


def test_metrics():
    assert cmse_location(7.5, 8.0) == pytest.approx(0.25)
    assert cmse_location([1.0, 2.0], [1.0, 4.0]) == pytest.approx(4.0)
    grid = np.linspace(0, 20, 2001)
    # wall inferred at 7 instead of 8: 1/20 of the grid is misclassified
    assert cmse_grid(halfspace_indicator(8.0), halfspace_indicator(7.0), grid) == pytest.approx(0.05, abs=1e-3)
    assert mean_std([1.0, 3.0]) == (2.0, 1.0)
    with pytest.raises(ValueError, match="finite"):
        cmse_location(np.nan, 8.0)
