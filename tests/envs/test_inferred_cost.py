"""InferredConstraintCost: the cost of scripted states for each constraint family and mode, and bad inputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

from pbicrl.inference.constraints import AxisHalfspace, Ball, Box, Halfspace  # noqa: E402
from pbicrl.envs.inferred_cost import InferredConstraintCost, _inside_many  # noqa: E402
from pbicrl.envs.point_mass import PointMassEnv  # noqa: E402
from pbicrl.envs.regions import FEATURE_NAMES as NAV  # noqa: E402
from pbicrl.io.runs import read_run  # noqa: E402


def write_run(path: Path, names, ind, wp, params=None, pnames=(), constraints=None) -> Path:
    """A run directory as pbicrl infer writes it (one chain; draws along axis 0 of ``ind``)."""
    path.mkdir(parents=True)
    ind = np.asarray(ind, dtype=np.int8)[None]
    wp = np.asarray(wp, dtype=np.float64)[None]
    arrays = {"indicators": ind, "penalty_weights": wp, "log_likelihood": np.zeros(ind.shape[:2]),
              "feature_names": np.array(names, dtype=np.str_)}
    if params is not None:
        arrays |= {"parameters": np.asarray(params, dtype=np.float64)[None],
                   "parameter_names": np.array(pnames, dtype=np.str_)}
    np.savez(path / "chains.npz", **arrays)
    summary = {"schema_version": 1, "method": "pbicrl", "feature_names": list(names),
               "settings": {"constraints": constraints}}
    (path / "summary.json").write_text(json.dumps(summary))
    return path


@pytest.fixture
def nav_run(tmp_path):
    """Point-mass features: orange and red always on; inv_goal_distance on in 2 of 10 draws; goal never."""
    n = 10
    ind = np.zeros((n, 4), dtype=int)
    ind[:, 1] = ind[:, 2] = 1
    ind[:2, 0] = 1
    wp = np.zeros((n, 4))
    wp[:, 0] = -5.0
    wp[:, 1] = -np.arange(10, 30, 2)  # orange: -10 .. -28, median -19
    wp[:, 2] = -100.0
    return write_run(tmp_path / "nav", NAV, ind, wp)


@pytest.fixture
def wall_run(tmp_path):
    """Wall x >= theta with theta draws 8, 10, 12, 14 (always on; median 11), penalties -1 .. -4."""
    th = np.array([8.0, 10.0, 12.0, 14.0])
    ind = np.array([[0, 0, 1]] * 4)
    wp = np.zeros((4, 3))
    wp[:, 2] = [-1.0, -2.0, -3.0, -4.0]
    cons = [{"family": "axis_halfspace", "dims": [0], "name": "wall", "bounds": None, "direction": ">=",
             "resolved_bounds": [[0.0, 100.0]]}]
    return write_run(tmp_path / "wall", ("forward_displacement", "action_sq_norm", "wall"), ind, wp, th[:, None],
                     ("wall.threshold",), cons)


@pytest.fixture
def box_run(tmp_path):
    """One box constraint on 3-D states: draws [0, 1]^3 and [0, 2]^3 (median upper corner 1.5), both on."""
    params = np.array([[0, 0, 0, 1, 1, 1], [0, 0, 0, 2, 2, 2]], dtype=float)
    cons = [{"family": "box", "dims": [0, 1, 2], "name": "box", "bounds": None}]
    pn = [f"box.{p}" for p in Box((0, 1, 2)).param_names()]
    return write_run(tmp_path / "box", ("box",), [[1], [1]], [[-3.0], [-5.0]], params, pn, cons)


class StateEnv(gym.Env):
    """Scripted states: the action is the next state; info carries nothing."""

    def __init__(self, k: int = 3) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (k,), np.float64)
        self.action_space = gym.spaces.Box(-np.inf, np.inf, (k,), np.float64)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(self.observation_space.shape), {}

    def step(self, action):
        return np.asarray(action, dtype=np.float64), 1.0, False, False, {}


# --------------------------------------------------------------------------------------------- indicator features
def test_indicator_features_each_mode(nav_run):
    out, orange, red = [0.1, 0, 0, 1], [0.1, 1, 0, 1], [0.1, 0, 1, 1]
    phi = np.array([out, orange, red])
    env = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run)
    assert env.used == (1, 2)  # the selected set, P(c=1) > 0.5
    np.testing.assert_array_equal(env.costs(phi), [0, 1, 1])
    prob = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="probability")
    assert prob.used == (1, 2)  # P(c=1) >= threshold 0.5: inv_goal_distance (0.2) would charge every step
    np.testing.assert_allclose(prob.costs(phi), [0, 1, 1])
    low = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="probability", threshold=0.1)
    assert low.used == (0, 1, 2)
    np.testing.assert_allclose(low.costs(phi), [0.2 * 0.1, 0.02 + 1, 0.02 + 1])
    samp = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="sample")
    np.testing.assert_allclose(samp.costs(phi, draw=0), [0.1, 1.1, 1.1])  # draw 0 has inv_goal_distance on
    np.testing.assert_allclose(samp.costs(phi, draw=5), [0, 1, 1])
    pen = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="penalty")
    np.testing.assert_allclose(pen.costs(phi), [0, 19, 100])
    q = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="penalty", quantile=0.1)
    assert q.penalty["in_orange"] == pytest.approx(np.quantile(-np.arange(10, 30, 2), 0.1))


def test_point_mass_steps_through_orange(nav_run):
    env = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run)
    env.reset(seed=0, options={"position": [1.0, 14.5]})
    costs = [env.step([1.0, 0.0])[4]["cost"] for _ in range(10)]
    # orange disc centre (5.5, 14.5) radius 3 (open): x = 3 .. 8 inside
    assert costs == [0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]


def test_fold_into_reward(nav_run):
    env = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="penalty", fold_into_reward=True)
    env.reset(seed=0, options={"position": [2.0, 14.5]})
    _, r, _, _, info = env.step([1.0, 0.0])
    assert info["cost"] == pytest.approx(19.0)
    assert r == pytest.approx(info["reward_without_cost"] - 19.0)
    half = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, fold_into_reward=0.5)
    half.reset(seed=0, options={"position": [2.0, 14.5]})
    _, r, _, _, info = half.step([1.0, 0.0])
    assert r == pytest.approx(info["reward_without_cost"] - 0.5)


def test_sample_mode_draw_is_seeded_per_episode(nav_run):
    env = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="sample")
    draws = []
    for s in (3, 3, 4, 5, 6, 7, 8, 9):
        env.reset(seed=s)
        draws.append(env.draw)
    assert draws[0] == draws[1]
    assert len(set(draws)) > 1
    other = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="sample")
    other.reset(seed=4)
    assert other.draw == draws[2]


# --------------------------------------------------------------------------------------------- x >= theta
def test_axis_halfspace_each_mode(wall_run):
    env = StateEnv(1)
    x = np.array([[7.0], [9.0], [10.5], [11.0], [20.0]])
    ind = InferredConstraintCost(env, read_run(wall_run), state=lambda o, i: o, mode="indicator")
    assert ind.location["wall"] == pytest.approx([11.0])
    np.testing.assert_array_equal(ind.costs(states=x), [0, 0, 0, 1, 1])
    prob = InferredConstraintCost(env, wall_run, state=lambda o, i: o, mode="probability")
    np.testing.assert_allclose(prob.costs(states=x), [0, 0.25, 0.5, 0.5, 1.0])
    samp = InferredConstraintCost(env, wall_run, state=lambda o, i: o, mode="sample")
    np.testing.assert_array_equal(samp.costs(states=x, draw=0), [0, 1, 1, 1, 1])
    np.testing.assert_array_equal(samp.costs(states=x, draw=3), [0, 0, 0, 0, 1])
    pen = InferredConstraintCost(env, wall_run, state=lambda o, i: o, mode="penalty")
    np.testing.assert_allclose(pen.costs(states=x), [0, 0, 0, 2.5, 2.5])
    # stepping: info["cost"] follows the reached state
    ind.reset(seed=0)
    assert [ind.step([v])[4]["cost"] for v in (10.0, 11.0, 3.0)] == [0.0, 1.0, 0.0]


def test_axis_halfspace_below(tmp_path):
    cons = [{"family": "axis_halfspace", "dims": [1], "name": "floor", "direction": "<="}]
    run = write_run(tmp_path / "floor", ("floor",), [[1], [1]], [[-1.0], [-1.0]], [[2.0], [4.0]], ("floor.threshold",),
                    cons)
    env = InferredConstraintCost(StateEnv(2), run, state=lambda o, i: o)
    np.testing.assert_array_equal(env.costs(states=[[0, 2.9], [0, 3.0], [0, 5.0]]), [1, 1, 0])


def test_wall_env_uses_its_own_x_position(wall_run, tmp_path):
    from pbicrl.envs.mujoco_wall import make_wall_env

    env = InferredConstraintCost.from_run(make_wall_env("halfcheetah", constrained=False, max_episode_steps=5), wall_run)
    env.reset(seed=0)
    for _ in range(3):
        _, _, _, _, info = env.step(np.zeros(6))
        assert info["cost"] == float(info["x_position"] >= 11.0) == 0.0
    # a wall behind the start: every step costs
    th = np.array([[-5.0], [-5.0]])
    cons = [{"family": "axis_halfspace", "dims": [0], "name": "wall", "direction": ">="}]
    behind = write_run(tmp_path / "behind", ("forward_displacement", "action_sq_norm", "wall"),
                       [[0, 0, 1]] * 2, [[0, 0, -1.0]] * 2, th, ("wall.threshold",), cons)
    env = InferredConstraintCost.from_run(make_wall_env("halfcheetah", constrained=False, max_episode_steps=5), behind)
    env.reset(seed=0)
    assert [env.step(np.zeros(6))[4]["cost"] for _ in range(3)] == [1.0, 1.0, 1.0]


# --------------------------------------------------------------------------------------------- box
def test_box_each_mode(box_run):
    env = StateEnv(3)
    s = np.array([[0.5, 0.5, 0.5], [1.2, 0.5, 0.5], [1.8, 0.5, 0.5], [0.5, -0.1, 0.5]])
    ind = InferredConstraintCost(env, box_run, state=lambda o, i: o, mode="indicator")
    np.testing.assert_array_equal(ind.costs(states=s), [1, 1, 0, 0])  # median box [0, 1.5]^3
    prob = InferredConstraintCost(env, box_run, state=lambda o, i: o, mode="probability")
    np.testing.assert_allclose(prob.costs(states=s), [1, 0.5, 0.5, 0])
    samp = InferredConstraintCost(env, box_run, state=lambda o, i: o, mode="sample")
    np.testing.assert_array_equal(samp.costs(states=s, draw=0), [1, 0, 0, 0])
    np.testing.assert_array_equal(samp.costs(states=s, draw=1), [1, 1, 1, 0])
    pen = InferredConstraintCost(env, box_run, state=lambda o, i: o, mode="penalty")
    np.testing.assert_allclose(pen.costs(states=s), [4, 4, 0, 0])
    ind.reset(seed=0)
    assert [ind.step(v)[4]["cost"] for v in s] == [1.0, 1.0, 0.0, 0.0]


@pytest.mark.parametrize("c", [AxisHalfspace((1,)), AxisHalfspace((0,), direction="<="), Box((0, 2)), Ball((0, 1, 2)),
                               Halfspace((0, 1)), Halfspace((0, 1, 2))])
def test_vectorised_membership_matches_the_constraints_own(c):
    rng = np.random.default_rng(0)
    thetas = rng.uniform(-1.5, 1.5, (200, c.n_params))
    if c.family == "box":
        thetas[:, 2:] = thetas[:, :2] + rng.uniform(0, 2, (200, 2))
    if c.family == "ball":
        thetas[:, -1] = np.abs(thetas[:, -1])
    for s in rng.uniform(-1, 1, (20, 3)):
        many = _inside_many(c, s, thetas)
        one = np.array([c.inside(s[None], t)[0] for t in thetas])
        np.testing.assert_array_equal(many, one)
        assert 0 < many.sum() < len(thetas) or c.family == "box"


# --------------------------------------------------------------------------------------------- bad inputs
def test_feature_function_of_the_wrong_width(nav_run):
    env = InferredConstraintCost(StateEnv(2), nav_run, features=lambda o, i: np.zeros(3))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"features: the feature function returned shape \(3,\), expected \(4,\)"):
        env.step(np.zeros(2))
    with pytest.raises(ValueError, match="features: non-finite value of 'in_red'"):
        env.costs([0.0, 0.0, np.nan, 1.0])


def test_posterior_without_the_constraint(nav_run, tmp_path):
    with pytest.raises(ValueError, match=r"constraints: 'in_purple' not in the posterior"):
        InferredConstraintCost.from_run(PointMassEnv(), nav_run, constraints=["in_purple"])
    with pytest.raises(ValueError, match=r"'goal_not_reached' never active"):
        InferredConstraintCost.from_run(PointMassEnv(), nav_run, constraints=["goal_not_reached"])
    none_on = write_run(tmp_path / "none", NAV, np.zeros((5, 4)), np.zeros((5, 4)))
    with pytest.raises(ValueError, match=r"posterior: no constraint is selected"):
        InferredConstraintCost.from_run(PointMassEnv(), none_on)
    undefined = write_run(tmp_path / "undef", ("wall",), [[1]] * 2, [[-1.0]] * 2, [[1.0], [2.0]], ("wall.threshold",))
    with pytest.raises(ValueError, match=r"posterior: has parameters wall.threshold but no definition"):
        InferredConstraintCost(StateEnv(1), undefined, state=lambda o, i: o)
    with pytest.raises(ValueError, match="posterior: expected a Posterior"):
        InferredConstraintCost(StateEnv(1), {"indicators": 1})
    # named explicitly, a constraint outside the selected set is costed
    env = InferredConstraintCost.from_run(PointMassEnv(), nav_run, constraints=["inv_goal_distance"])
    assert env.used == (0,)


def test_env_without_the_needed_state(wall_run, box_run, nav_run):
    with pytest.raises(ValueError, match=r"state: the posterior has parametric constraints \['box'\].*pass state="):
        InferredConstraintCost(StateEnv(3), box_run)
    with pytest.raises(ValueError, match=r"features: .* pass features="):
        InferredConstraintCost(StateEnv(4), nav_run)
    with pytest.raises(ValueError, match=r"env: the point_mass environment's features .* are not the posterior's"):
        InferredConstraintCost.from_run(PointMassEnv(), wall_run)
    narrow = InferredConstraintCost(StateEnv(3), box_run, state=lambda o, i: o[:2])
    narrow.reset(seed=0)
    with pytest.raises(ValueError, match=r"state: the state function returned shape \(2,\).*at least 3 column"):
        narrow.step(np.zeros(3))


def test_bad_options(nav_run, tmp_path):
    with pytest.raises(ValueError, match="mode: expected one of"):
        InferredConstraintCost.from_run(PointMassEnv(), nav_run, mode="max")
    with pytest.raises(ValueError, match=r"quantile: must be in \(0, 1\)"):
        InferredConstraintCost.from_run(PointMassEnv(), nav_run, mode="penalty", quantile=1.0)
    with pytest.raises(ValueError, match="fold_into_reward"):
        InferredConstraintCost.from_run(PointMassEnv(), nav_run, fold_into_reward=-1.0)
    bonus = write_run(tmp_path / "bonus", NAV, [[0, 1, 0, 0]] * 3, [[0, 2.0, 0, 0]] * 3)
    with pytest.raises(ValueError, match=r"mode 'penalty': .*'in_orange'.* not a penalty"):
        InferredConstraintCost.from_run(PointMassEnv(), bonus, mode="penalty")
    with pytest.raises(FileNotFoundError, match="no such directory"):
        InferredConstraintCost.from_run(PointMassEnv(), tmp_path / "missing")


def test_describe_is_json_ready(wall_run):
    env = InferredConstraintCost(StateEnv(1), wall_run, state=lambda o, i: o, mode="penalty")
    d = json.loads(json.dumps(env.describe()))
    assert d["terms"] == [{"name": "wall", "kind": "parametric", "p_constraint": 1.0, "family": "axis_halfspace",
                           "dims": [0], "median_location": {"threshold": 11.0}, "penalty_quantile": -2.5}]


# --------------------------------------------------------------------------------------------- conservative mode
def test_conservative_is_the_default_for_parametric_constraints(wall_run, box_run, nav_run):
    assert InferredConstraintCost(StateEnv(1), wall_run, state=lambda o, i: o).mode == "conservative"
    assert InferredConstraintCost(StateEnv(3), box_run, state=lambda o, i: o).mode == "conservative"
    assert InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run).mode == "indicator"  # features only


def test_conservative_wall_sits_at_the_edge_nearest_the_safe_side(wall_run):
    x = np.array([[7.0], [7.99], [8.0], [9.0], [20.0]])
    env = InferredConstraintCost(StateEnv(1), wall_run, state=lambda o, i: o)
    # draws 8, 10, 12, 14: the lowest threshold the posterior allows, not the median 11
    assert env.conservative_location["wall"] == pytest.approx([8.0])
    np.testing.assert_array_equal(env.costs(states=x), [0, 0, 1, 1, 1])
    assert env.describe()["terms"][0]["conservative_location"] == {"threshold": 8.0}
    env.reset(seed=0)
    assert [env.step([v])[4]["cost"] for v in (7.5, 9.0, 3.0)] == [0.0, 1.0, 0.0]
    assert env.describe()["terms"][0]["boundary_from"].endswith("; the run records no dataset")
    # good demonstrations that stopped at 6.5: the boundary is just beyond them
    safe = np.array([[1.0], [6.5], [4.0]])
    tight = InferredConstraintCost(StateEnv(1), wall_run, state=lambda o, i: o, safe_states=safe)
    assert 6.5 < tight.conservative_location["wall"][0] < 6.5 + 1e-9
    np.testing.assert_array_equal(tight.costs(states=[[6.5], [6.6], [7.0]]), [0, 1, 1])
    # good demonstrations that went to 9.5 (past the lowest draw, 8): the states they showed safe are not charged
    loose = InferredConstraintCost(StateEnv(1), wall_run, state=lambda o, i: o, safe_states=[[9.5]])
    np.testing.assert_array_equal(loose.costs(states=[[9.0], [9.5], [9.6]]), [0, 0, 1])
    assert loose.describe()["terms"][0]["boundary_from"] == "safe_states (given)"
    none = InferredConstraintCost(StateEnv(1), wall_run, state=lambda o, i: o, safe_states=None)
    assert none.conservative_location["wall"] == pytest.approx([8.0])
    with pytest.raises(ValueError, match="safe_states: used only by mode 'conservative'"):
        InferredConstraintCost(StateEnv(1), wall_run, state=lambda o, i: o, mode="indicator", safe_states=safe)
    with pytest.raises(ValueError, match="safe_states: expected a non-empty finite"):
        InferredConstraintCost(StateEnv(1), wall_run, state=lambda o, i: o, safe_states=[[np.nan]])


def test_conservative_weight_is_the_posterior_probability(tmp_path):
    """The posterior says how hard (P(c=1) = 0.75), not where (the lowest active threshold, 10)."""
    th = np.array([[8.0], [10.0], [12.0], [14.0]])
    ind = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 1], [0, 0, 1]])  # the draw at 8 has c = 0
    cons = [{"family": "axis_halfspace", "dims": [0], "name": "wall", "direction": ">="}]
    run = write_run(tmp_path / "w", ("forward_displacement", "action_sq_norm", "wall"), ind, np.zeros((4, 3)), th,
                    ("wall.threshold",), cons)
    env = InferredConstraintCost(StateEnv(1), run, state=lambda o, i: o)
    assert env.conservative_location["wall"] == pytest.approx([10.0])
    np.testing.assert_allclose(env.costs(states=[[9.0], [10.0], [30.0]]), [0, 0.75, 0.75])


def test_conservative_below_and_box_union(tmp_path, box_run):
    cons = [{"family": "axis_halfspace", "dims": [0], "name": "floor", "direction": "<="}]
    run = write_run(tmp_path / "f", ("floor",), [[1], [1], [1]], [[-1.0]] * 3, [[-3.0], [-2.0], [-4.0]],
                    ("floor.threshold",), cons)
    env = InferredConstraintCost(StateEnv(1), run, state=lambda o, i: o)
    assert env.conservative_location["floor"] == pytest.approx([-2.0])  # x <= theta: the highest draw
    np.testing.assert_array_equal(env.costs(states=[[-2.5], [-1.9]]), [1, 0])
    box = InferredConstraintCost(StateEnv(3), box_run, state=lambda o, i: o)
    s = np.array([[0.5, 0.5, 0.5], [1.8, 0.5, 0.5], [2.5, 0.5, 0.5]])
    np.testing.assert_array_equal(box.costs(states=s), [1, 1, 0])  # inside [0, 1]^3 or [0, 2]^3
    assert box.describe()["terms"][0]["conservative_region"].startswith("union")


def test_probability_threshold(nav_run, tmp_path):
    with pytest.raises(ValueError, match=r"threshold: must be in \(0, 1\]"):
        InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="probability", threshold=0.0)
    weak = write_run(tmp_path / "weak", NAV, [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0]], np.zeros((3, 4)))
    with pytest.raises(ValueError, match=r"no constraint is likely enough \(P\(c=1\) < threshold 0.5"):
        InferredConstraintCost.from_run(PointMassEnv("nominal"), weak, mode="probability")
    assert InferredConstraintCost.from_run(PointMassEnv("nominal"), weak, mode="probability",
                                           threshold=0.3).used == (0, 1)
    # a budget of 0.1 per episode is reachable once the unlikely feature is dropped: outside the regions, no cost
    env = InferredConstraintCost.from_run(PointMassEnv("nominal"), nav_run, mode="probability")
    assert env.costs(np.array([[0.3, 0, 0, 1]]))[0] == 0.0
    assert env.describe()["threshold"] == 0.5


def test_conservative_wall_from_the_runs_own_good_demonstrations(tmp_path):
    """safe_states='auto' (default): the best group of the dataset recorded in the run's summary.json."""
    from pbicrl.inference.data import Dataset

    states = np.r_[np.linspace(0, 7.2, 5), np.linspace(0, 12.0, 5)][:, None]
    ds = Dataset(features=np.ones((10, 1)), offsets=[0, 5, 10], group=[1, 2], states=states, feature_names=("f",))
    data = ds.save(tmp_path / "demos.npz")
    th = np.array([[6.0], [8.0], [10.0]])
    cons = [{"family": "axis_halfspace", "dims": [0], "name": "wall", "direction": ">="}]
    run = write_run(tmp_path / "r", ("f", "wall"), [[0, 1]] * 3, np.zeros((3, 2)), th, ("wall.threshold",), cons)
    summary = json.loads((run / "summary.json").read_text())
    summary["extra"] = {"data": {"path": str(data)}}
    (run / "summary.json").write_text(json.dumps(summary))
    env = InferredConstraintCost(StateEnv(1), run, state=lambda o, i: o, constraints=["wall"])
    assert 7.2 < env.conservative_location["wall"][0] < 7.2 + 1e-9  # not the lowest draw, 6
    assert env.describe()["terms"][0]["boundary_from"] == f"the good demonstrations (group 1 of {data})"
    np.testing.assert_array_equal(env.costs(states=[[7.0], [7.2], [7.3]]), [0, 0, 1])
    data.unlink()  # the dataset moved: the posterior's draws, and the description says why
    moved = InferredConstraintCost(StateEnv(1), run, state=lambda o, i: o, constraints=["wall"])
    assert moved.conservative_location["wall"] == pytest.approx([6.0])
    assert "is not there" in moved.describe()["terms"][0]["boundary_from"]
    with pytest.raises(ValueError, match="safe_states: expected an"):
        InferredConstraintCost(StateEnv(1), run, state=lambda o, i: o, safe_states="group1")
