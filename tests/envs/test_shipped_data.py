"""The datasets and policies shipped in pbicrl/data load, validate and match their states.

The point-mass and Fetch-Reach datasets are built the paper's way
(``pbicrl envs demos --paper-protocol``): one start distribution, a mix of the good and the
violating policy, every trajectory grouped by the worst region it entered.  The tests check
those properties on the files themselves, not stored numbers.
"""

import json
from pathlib import Path

import numpy as np
import pytest

import pbicrl
from pbicrl.inference.data import load_dataset

DATA = Path(pbicrl.__file__).resolve().parent / "data"
MB = 1024 * 1024
NAV = ["point_mass", "fetch_reach"]
SMD_LIMIT = 0.3


def test_grid_dataset_shipped_and_identical_to_builder():
    from pbicrl.envs.grid import grid_dataset

    ds = load_dataset(DATA / "grid.npz")
    ref = grid_dataset()
    assert ds.group.tolist() == [1, 2, 3]
    np.testing.assert_array_equal(ds.features, ref.features)
    np.testing.assert_array_equal(ds.states, ref.states)
    assert ds.feature_names == ("grey", "orange", "red")


def _task(name):
    from pbicrl.envs.regions import Box, Disc, NavigationTask

    # the paper's regions, restated here so that a change to the environment constants is caught
    if name == "point_mass":
        return NavigationTask(goal=Disc((20.0, 20.0), 3.0, closed=True), orange=Disc((5.5, 14.5), 3.0),
                              red=Disc((14.5, 5.5), 3.0), true_weights=(1, -10, -100, -1), nominal_weights=(1, 0, 0, -1))
    return NavigationTask(goal=Disc((0.95, 0.90, 0.72), 0.05, closed=True),
                          orange=Box((0.7, 0.70, 0.7), (1.1, 0.85, 1.4)), red=Box((0.7, 1.00, 0.7), (1.1, 1.10, 1.4)),
                          true_weights=(0.1, -20, -100, -5), nominal_weights=(0.1, 0, 0, -5))


def _load(name):
    path = DATA / f"{name}.npz"
    return path, load_dataset(path), json.loads(path.with_suffix(".json").read_text())


@pytest.mark.parametrize("name", NAV)
def test_navigation_dataset_groups_match_states(name):
    from pbicrl.envs.regions import FEATURE_NAMES

    task = _task(name)
    path, ds, report = _load(name)
    assert path.stat().st_size < 5 * MB
    assert ds.feature_names == FEATURE_NAMES
    np.testing.assert_allclose(ds.nominal_weights, task.nominal_weights)
    assert ds.states is not None and ds.states.shape[1] == task.dim
    counts = ds.group_counts()
    assert set(counts) == {1, 2, 3}
    assert min(counts.values()) >= max(300, report["n_per_group_min"])  # the issue asks for >= 300 per group
    # features are recomputed from the states, and every group label follows from the states
    np.testing.assert_allclose(ds.features, task.features(ds.states), rtol=1e-12)
    for i in range(ds.n_trajectories):
        s = ds.trajectory_states(i)
        assert ds.group[i] == task.group(s)
        assert task.reached(s[-1:])[0]  # every demonstration reaches the goal ...
        assert not task.reached(s[:-1]).any()  # ... and stops there
    assert report["group_counts"] == {f"G{k}": v for k, v in counts.items()}
    assert report["file_bytes"] == path.stat().st_size


@pytest.mark.parametrize("name", NAV)
def test_every_trajectory_starts_from_the_one_start_distribution(name):
    _, ds, report = _load(name)
    starts = ds.states[ds.offsets[:-1]]
    if name == "point_mass":
        assert report["env_kwargs"] == {"start": "balanced"}
        # the "balanced" strips: [0, 2.5] x [5, 19] along the left and the bottom edge (docs/envs.md)
        left = (starts[:, 0] >= 0) & (starts[:, 0] <= 2.5) & (starts[:, 1] >= 5) & (starts[:, 1] <= 19)
        bottom = (starts[:, 1] >= 0) & (starts[:, 1] <= 2.5) & (starts[:, 0] >= 5) & (starts[:, 0] <= 19)
        assert np.all(left | bottom)
        # region-free starts lie both above and below the orange disc (and its mirror image for red):
        # what balances the nominal features (G1 starts span the strips' length, not only their ends)
        g1 = starts[ds.group == 1]
        along = np.where(g1[:, 0] <= 2.5, g1[:, 1], g1[:, 0])
        assert (along < 8).any() and (along > 16).any()
    else:
        from pbicrl.envs.fetch_reach import START_BOXES

        assert report["env_kwargs"] == {"start": "balanced"}
        lo, hi = (np.array(b) for b in START_BOXES["balanced"])
        assert np.all(starts >= lo - 0.01) and np.all(starts <= hi + 0.01)  # the gripper settles within 1 cm
    # both policies start from the same distribution: no per-group start rule in the report
    assert report["protocol"] == "paper"


@pytest.mark.parametrize("name", NAV)
def test_paper_protocol_report_accounts_for_every_rollout(name):
    _, ds, report = _load(name)
    assert 0.0 < report["p_good"] < 1.0  # a mix of both policies
    roll = report["rollouts"]
    assert set(roll) == {"good", "violating"}
    assert sum(r["episodes"] for r in roll.values()) == report["total_rollouts"]
    rejected = 0
    for r in roll.values():
        for g in ("G1", "G2", "G3"):
            # every rollout is either kept or rejected by the (only) filter, goal reached
            assert r["kept_per_group"][g] + r["rejected_goal_not_reached_per_group"][g] == r["group_of_rollouts"][g]
        rejected += sum(r["rejected_goal_not_reached_per_group"].values())
        assert sum(r["group_of_rollouts"].values()) == r["episodes"]
        assert r["reached_goal"] == sum(r["kept_per_group"].values())
    assert report["filters"]["goal_reached"]["rejected"] == rejected
    assert sum(sum(r["kept_per_group"].values()) for r in roll.values()) == ds.n_trajectories
    # group composition, and the per-trajectory policy letters in file order
    letters = np.array(list(report["trajectory_policy"]))
    assert letters.size == ds.n_trajectories and set(letters) <= {"g", "v"}
    for k in (1, 2, 3):
        comp = report["group_composition"][f"G{k}"]
        assert comp == {"good": roll["good"]["kept_per_group"][f"G{k}"], "violating": roll["violating"]["kept_per_group"][f"G{k}"]}
        assert int((letters[ds.group == k] == "g").sum()) == comp["good"]
    assert report["group_composition"]["G1"]["good"] > 0  # the good policy contributes to G1
    assert report["command"].startswith(f"python -m pbicrl.envs demos --env {name} --paper-protocol")


def _smd(a, b):
    pooled = np.sqrt(((a.size - 1) * a.var(ddof=1) + (b.size - 1) * b.var(ddof=1)) / (a.size + b.size - 2))
    return (a.mean() - b.mean()) / pooled


def _nominal_smds(name):
    _, ds, report = _load(name)
    mf = ds.mean_features  # per-trajectory mean of each feature (what the ranking likelihood scores)
    out = {}
    for j, fname in enumerate(ds.feature_names):
        if ds.nominal_weights[j] == 0:
            continue  # constraint features: they are meant to differ
        for a, b in ((1, 2), (1, 3), (2, 3)):
            out[(fname, a, b)] = _smd(mf[ds.group == a, j], mf[ds.group == b, j])
    return out, report


@pytest.mark.parametrize("name", NAV)
def test_report_states_the_feature_balance_of_the_file(name):
    smds, report = _nominal_smds(name)
    fb = report["feature_balance"]
    assert set(fb["features"]) == {f for f, _, _ in smds} == {"inv_goal_distance", "goal_not_reached"}
    for (f, a, b), d in smds.items():
        assert fb["smd"][f][f"G{a}-G{b}"] == pytest.approx(d, rel=1e-9, abs=1e-12)
    assert fb["max_abs_smd"] == pytest.approx(max(abs(d) for d in smds.values()))


# The issue's target, met since the "balanced" start distributions (docs/envs.md, "Balance of the nominal
# features"): point mass max |SMD| 0.12, Fetch-Reach 0.24.
@pytest.mark.parametrize("name", NAV)
def test_nominal_features_balanced_across_groups(name):
    """Standardised mean difference of every nominal feature between any two groups < 0.3 (the issue's target)."""
    smds, _ = _nominal_smds(name)
    worst = max(smds, key=lambda k: abs(smds[k]))
    assert abs(smds[worst]) < SMD_LIMIT, f"{worst}: SMD {smds[worst]:+.3f}"


@pytest.mark.parametrize("name", NAV)
def test_nominal_features_far_closer_than_in_the_good_vs_violating_design(name):
    """Guard: every nominal-feature SMD below 0.5 (the earlier G1-from-the-good-policy data had 1.9-2.8)."""
    smds, _ = _nominal_smds(name)
    worst = max(smds, key=lambda k: abs(smds[k]))
    assert abs(smds[worst]) < 0.5, f"{worst}: SMD {smds[worst]:+.3f}"


def _shipped_policies():
    out = []
    for name in NAV:
        report = json.loads((DATA / f"{name}.json").read_text())
        out += [(name, role, Path(r["policy"]).name) for role, r in report["rollouts"].items()]
    return out


@pytest.mark.parametrize(("env", "role", "file"), _shipped_policies())
def test_policies_behind_the_datasets_are_shipped_and_load(env, role, file):
    path = DATA / "policies" / file
    assert file == f"{env}_{role}.zip"
    assert path.stat().st_size < 4 * MB
    budget = json.loads(path.with_suffix(".budget.json").read_text())
    assert budget["status"] == "complete" and budget["done_steps"] > 0
    assert budget["metadata"]["reward_weights"] == ("true" if role == "good" else "nominal")
    pytest.importorskip("stable_baselines3")
    from pbicrl.demonstrators.sac import load_policy

    policy = load_policy(path)
    dim = 2 if env == "point_mass" else 3
    action, _ = policy.predict(np.zeros(dim, dtype=np.float32), deterministic=True)
    assert action.shape == (dim,) and np.all(np.abs(action) <= 1.0)
