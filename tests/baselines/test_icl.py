"""ICL baseline: Lagrangian update, constraint loss, weights, location read-off, a point-mass smoke run."""

import json
import math

import numpy as np
import pytest

from pbicrl.errors import PbicrlWarning

torch = pytest.importorskip("torch")
pytest.importorskip("gymnasium")

from pbicrl.baselines.icl import (
    ConstraintNet,
    ICLConfig,
    accrual,
    constraint_location,
    constraint_loss,
    discount_matrix,
    expert_coordinates,
    icl_preset,
    mixture_weights,
    point_mass_expert_demos,
    run_icl,
    run_icl_task,
)
from pbicrl.baselines.ppo_lagrangian import (
    PPOLagConfig,
    discounted_sum,
    gae,
    lagrange_update,
)


# --------------------------------------------------------------------------------------------- PPO-Lagrangian
def test_lagrange_multiplier_rises_with_excess_cost_and_falls_otherwise():
    assert lagrange_update(1.0, expected_cost=5.0, budget=2.0, lr=0.1) == pytest.approx(1.3)
    assert lagrange_update(1.0, expected_cost=0.0, budget=2.0, lr=0.1) == pytest.approx(0.8)
    assert lagrange_update(0.05, expected_cost=0.0, budget=2.0, lr=0.1) == 0.0  # projected onto lambda >= 0
    assert lagrange_update(9.9, expected_cost=100.0, budget=0.0, lr=1.0, lam_max=10.0) == 10.0
    assert lagrange_update(1.0, expected_cost=2.0, budget=2.0, lr=0.1) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="finite"):
        lagrange_update(1.0, math.nan, 1.0, 0.1)


def test_ppo_lagrangian_multiplier_follows_the_expected_discounted_cost():
    from pbicrl.baselines.ppo_lagrangian import PPOLagrangian
    from pbicrl.envs.point_mass import PointMassEnv

    def run(cost_value, lam0, steps):
        cfg = PPOLagConfig(n_envs=2, n_steps=64, n_epochs=1, minibatch_size=64, cost_budget=1.0, lagrange_lr=0.1,
                           lagrange_init=lam0)
        p = PPOLagrangian(lambda: PointMassEnv(max_steps=10), lambda o, i: np.asarray(o)[:2],
                          lambda c: np.full(len(c), cost_value), cfg, seed=0)
        p.learn(steps)  # one update per 2 x 64 steps
        p.close()
        return p

    hot = run(1.0, 0.0, 128)  # every 10-step episode costs sum_t 0.99^t ~ 9.56 > budget 1
    assert hot.history[0]["ep_cost"] == pytest.approx(discounted_sum(np.ones(10), 0.99), rel=1e-6)
    assert hot.lam == pytest.approx(0.1 * (hot.history[0]["ep_cost"] - 1.0))
    cold = run(0.0, 0.15, 256)  # no cost: the multiplier falls by lr * budget per update, to 0
    assert cold.lam == 0.0 and cold.history[0]["lam_next"] == pytest.approx(0.05)


def test_gae_matches_hand_computation():
    r = np.array([[1.0], [2.0], [3.0]])
    v = np.array([[0.5], [1.0], [1.5]])
    done = np.array([[0.0], [1.0], [0.0]])  # episode ends after step 1; step 2 starts a new one
    adv, ret = gae(r, v, done, np.array([2.0]), gamma=0.9, lam=0.5)
    d2 = 3.0 + 0.9 * 2.0 - 1.5
    d1 = 2.0 - 1.0  # terminal: no bootstrap
    d0 = 1.0 + 0.9 * 1.0 - 0.5
    assert adv[:, 0] == pytest.approx([d0 + 0.45 * d1, d1, d2])
    assert ret == pytest.approx(adv + v)
    assert discounted_sum(np.array([1.0, 1.0, 1.0]), 0.5) == pytest.approx(1.75)


def test_ppo_config_validation_names_the_option():
    with pytest.raises(ValueError, match="ppo.n_envs"):
        PPOLagConfig(n_envs=0).validate()
    with pytest.raises(ValueError, match="ppo.gamma"):
        PPOLagConfig(gamma=1.5).validate()
    with pytest.raises(ValueError, match="icl.weighting"):
        ICLConfig(weighting="mean").validate()
    with pytest.raises(ValueError, match="unknown option"):
        ICLConfig.from_dict({"roundz": 3})
    with pytest.raises(ValueError, match="budget"):
        icl_preset("huge")
    cfg = icl_preset("default", "halfcheetah")
    assert cfg.ppo.cost_budget == cfg.beta and cfg.ppo.cost_gamma == cfg.gamma
    assert ICLConfig.from_dict(cfg.to_dict()).to_dict() == cfg.to_dict()


# --------------------------------------------------------------------------------------------- constraint loss
def _step_cost(threshold):
    return lambda s: (s[..., 0] >= threshold).float()


def test_constraint_loss_on_a_hand_made_example():
    gamma = 0.5
    agent_a = [np.array([[0.0], [2.0], [3.0]])]            # enters x >= 1 at steps 1 and 2
    agent_b = [np.array([[0.0], [0.0]]), np.array([[5.0]])]  # J = 0 and J = 1
    expert = [np.array([[0.0], [1.0]]), np.array([[0.0], [0.0]])]  # J = 0.5 and 0
    mats = [discount_matrix(agent_a, gamma), discount_matrix(agent_b, gamma)]
    exp = discount_matrix(expert, gamma)
    cost = _step_cost(1.0)
    # J_a = 0.5 + 0.25 = 0.75; J_b = mean(0, 1) = 0.5; J_E = mean(0.5, 0) = 0.25
    loss, info = constraint_loss(cost, mats, [0.25, 0.75], exp, beta=0.1, hinge_weight=10.0)
    assert info["J_agent"] == pytest.approx([0.75, 0.5])
    assert info["J_expert"] == pytest.approx(0.25)
    assert float(loss) == pytest.approx(-(0.25 * 0.75 + 0.75 * 0.5) + 10.0 * (0.25 - 0.1))
    # expert within budget: the hinge is inactive
    loss2, _ = constraint_loss(cost, mats, [0.25, 0.75], exp, beta=0.3, hinge_weight=10.0)
    assert float(loss2) == pytest.approx(-(0.25 * 0.75 + 0.75 * 0.5))
    with pytest.raises(ValueError, match="weights"):
        constraint_loss(cost, mats, [0.5, 0.6], exp, beta=0.3, hinge_weight=1.0)


def test_constraint_loss_gradient_raises_agent_only_states_and_lowers_expert_states():
    """One gradient step on per-state costs: states only the agent visits go up; over budget, expert states go down."""
    logits = torch.zeros(3, requires_grad=True)  # costs of three discrete states 0, 1, 2

    def cost(s):
        return torch.sigmoid(logits)[s[..., 0].long()]

    agent = [discount_matrix([np.array([[0.0], [2.0], [2.0]])], 0.9)]
    expert = discount_matrix([np.array([[0.0], [1.0], [1.0]])], 0.9)
    loss, info = constraint_loss(cost, agent, [1.0], expert, beta=0.1, hinge_weight=5.0)
    assert info["J_expert"] > 0.1
    loss.backward()
    g = logits.grad.numpy()
    assert g[2] < 0          # agent-only state: descent increases its cost
    assert g[1] > 0          # expert-only state while over budget: descent decreases its cost
    assert g[0] > 0          # shared start state: hinge weight 5 > agent weight 1, so it decreases


def test_mixture_weights_favour_policies_unlike_the_expert():
    edges = [np.linspace(0, 10, 11)]
    expert = [np.full((20, 1), 2.5)]
    like = [np.full((20, 1), 2.5)]
    unlike = [np.full((20, 1), 8.5)]
    half = [np.concatenate([np.full((10, 1), 2.5), np.full((10, 1), 8.5)])]
    acc = [accrual(t, 1.0, edges) for t in (like, unlike, half)]
    assert acc[0].sum() == pytest.approx(1.0)
    w = mixture_weights(acc, accrual(expert, 1.0, edges))
    assert w == pytest.approx([0.0, 1 / 1.5, 0.5 / 1.5])
    assert mixture_weights(acc[:1], acc[0]) == pytest.approx([1.0])  # all equal to the expert: uniform
    assert mixture_weights(acc, acc[0], "last") == pytest.approx([0, 0, 1])
    assert mixture_weights(acc, acc[0], "uniform") == pytest.approx([1 / 3] * 3)


def test_constraint_location_read_off():
    g = np.linspace(0.0, 10.0, 11)
    v = 1 / (1 + np.exp(-(g - 6.3) * 50))
    assert constraint_location(v, g) == pytest.approx(6.3, abs=0.5)
    assert constraint_location(np.array([0.0, 0.2, 0.8]), np.array([0.0, 1.0, 2.0])) == pytest.approx(1.5)
    assert constraint_location(np.zeros(11), g) is None
    assert constraint_location(np.ones(11), g) == 0.0
    net = ConstraintNet(1, (8,), [0.0], [1.0], init_bias=-5.0)
    assert np.all(net.numpy(g) < 0.01)  # a new net starts nearly unconstrained


def test_expert_coordinates_uses_the_good_group():
    from pbicrl.inference.data import Dataset

    feats = [np.zeros((5, 2)) for _ in range(6)]
    states = [np.full((5, 1), float(i)) for i in range(6)]
    ds = Dataset.from_trajectories(features=feats, group=[1, 2, 1, 2, 1, 1], states=states)
    ex = expert_coordinates(ds, n=None)
    assert [float(t[0, 0]) for t in ex] == [0.0, 2.0, 4.0, 5.0]
    assert len(expert_coordinates(ds, n=2, seed=3)) == 2
    with pytest.raises(ValueError, match="group 3"):
        expert_coordinates(ds, group=3)
    with pytest.raises(ValueError, match="states"):
        expert_coordinates(Dataset.from_trajectories(features=feats, group=[1, 2] * 3))


# --------------------------------------------------------------------------------------------- smoke run
def test_point_mass_smoke_run_and_resume(tmp_path):
    from pbicrl.envs.point_mass import POINT_MASS_TASK

    expert = point_mass_expert_demos(20, seed=0)
    for t in expert:  # the scripted expert never enters a disc
        assert not (POINT_MASS_TASK.orange.contains(t).any() or POINT_MASS_TASK.red.contains(t).any())
    cfg = icl_preset("smoke", "point_mass")
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        run_icl("point_mass", expert, cfg, out, seed=1, progress=False, max_session_steps=1000)
    budget = json.loads((out / "budget.json").read_text())
    assert budget["status"] == "interrupted" and 0 < budget["done_ppo_steps"] < cfg.total_steps
    s = run_icl("point_mass", expert, cfg, out, seed=1, progress=False)
    assert s["sessions"] == 2 and s["ppo_steps"] >= cfg.total_steps
    assert len(s["history"]) == cfg.rounds
    assert 0.0 <= s["cmse_grid"] <= 1.0 and s["location"] is None  # 2-D: no scalar location
    h = s["history"][-1]
    assert len(h["weights"]) == cfg.rounds and h["weights"] == pytest.approx(np.array(h["weights"]) / sum(h["weights"]))
    # the adjustment keeps the expert near its budget while the learned policies' cost is far above it
    assert h["J_expert"] <= cfg.beta * 1.5
    assert max(h["J_agent"]) > 3 * cfg.beta
    assert (out / "constraint.pt").exists() and (out / "summary.json").exists()
    again = run_icl("point_mass", expert, cfg, out, seed=1, progress=False)  # finished: read back, not rerun
    assert again["sessions"] == 2 and again["cmse_grid"] == s["cmse_grid"]
    with pytest.raises(ValueError, match="different expert data"):
        run_icl("point_mass", expert[:-1], cfg, out, seed=1, progress=False)
    with pytest.raises(ValueError, match="different ICL configuration"):
        run_icl("point_mass", expert, icl_preset("default", "point_mass"), out, seed=1, progress=False)


def test_run_icl_task_on_a_dataset(tmp_path):
    from pbicrl.inference.data import Dataset

    expert = point_mass_expert_demos(12, seed=2)
    bad = point_mass_expert_demos(4, seed=3)
    ds = Dataset.from_trajectories(features=[np.zeros((len(t), 1)) for t in expert + bad],
                                   group=[1] * len(expert) + [2] * len(bad), states=expert + bad)
    path = tmp_path / "pm.npz"
    ds.save(path)
    res = run_icl_task({"env": "point_mass", "data": str(path), "budget": "smoke", "seed": 0,
                        "icl": {"rounds": 1, "ppo": {"n_steps": 128}}}, tmp_path / "out")
    assert res["n_expert"] == 12 and res["rounds"] == 1 and res["budget"] == "smoke"
    assert (tmp_path / "out" / "icl" / "summary.json").exists()
    with pytest.raises(ValueError, match="env"):
        run_icl_task({"env": "cartpole", "data": str(path)}, tmp_path / "x")
    with pytest.warns(PbicrlWarning, match="'dataset' is deprecated"), pytest.raises(ValueError, match="env"):
        run_icl_task({"env": "cartpole", "dataset": str(path)}, tmp_path / "x")


def test_reproduce_icl_smoke(tmp_path, monkeypatch):
    """`pbicrl reproduce icl` on a synthetic stand-in wall dataset with the smoke budget; `all` leaves it out."""
    pytest.importorskip("mujoco")
    from pbicrl.experiments.reproduce import EXPERIMENTS, reproduce
    from pbicrl.inference.synthetic import make_wall_problem

    assert "icl" in EXPERIMENTS
    data = tmp_path / "wall.npz"
    make_wall_problem(100, length=60, seed=0).dataset.save(data)
    monkeypatch.setenv("PBICRL_ICL_BUDGET", "smoke")
    (report,) = reproduce("icl", out=tmp_path, iterations=2000, seeds=1, executor="serial", progress=False,
                          data={"halfcheetah": str(data), "ant": str(data)})
    text = report.read_text()
    assert "paper ICL" in text and "CMSE (grid)" in text and "budget `smoke`" in text
    res = json.loads((tmp_path / "icl" / "results.json").read_text())
    for env in ("halfcheetah", "ant"):
        row = res["envs"][env]
        assert row["icl"]["n_expert"] == [100]
        assert 0.0 <= row["icl"]["cmse_grid"][0] <= 1.0
        assert row["pbicrl"]["runtime_s"][0] > 0 and row["icl"]["runtime_s"][0] > 0
        assert row["default"]["runtime_s"][0] > 0 and len(row["default"]["theta"]) == 1  # pbicrl's default model
    assert "pbicrl default, MAP" in text
    # one environment only: the other is not run (its finished tasks above are simply not read)
    monkeypatch.setenv("PBICRL_ICL_ENVS", "halfcheetah")
    reproduce("icl", out=tmp_path, iterations=2000, seeds=1, executor="serial", progress=False,
              data={"halfcheetah": str(data), "ant": str(tmp_path / "missing.npz")})
    assert list(json.loads((tmp_path / "icl" / "results.json").read_text())["envs"]) == ["halfcheetah"]
    for bad in ("cheetah", "", "ant,ant"):
        monkeypatch.setenv("PBICRL_ICL_ENVS", bad)
        with pytest.raises(ValueError, match="PBICRL_ICL_ENVS"):
            reproduce("icl", out=tmp_path, seeds=1, executor="serial", progress=False, data={"halfcheetah": str(data)})
    monkeypatch.delenv("PBICRL_ICL_ENVS")
    monkeypatch.setenv("PBICRL_ICL_BUDGET", "enormous")
    with pytest.raises(ValueError, match="PBICRL_ICL_BUDGET"):
        reproduce("icl", out=tmp_path, seeds=1, executor="serial", progress=False, data={"halfcheetah": str(data)})


def test_reproduce_all_excludes_icl(monkeypatch, tmp_path):
    from pbicrl.experiments import reproduce as rep

    called = []
    for name in list(rep.EXPERIMENTS):
        monkeypatch.setitem(rep.EXPERIMENTS, name, lambda ctx, n=name: called.append(n) or tmp_path)
    rep.reproduce("all", out=tmp_path, progress=False)
    assert "icl" not in called and "grid" in called


# --------------------------------------------------------------------------------------------- ICRL benchmark tasks
@pytest.mark.parametrize("name, task, wall, side", [
    ("icrl_halfcheetah", "halfcheetah", -3.0, "behind"), ("icrl_ant", "ant", -3.0, "behind"),
    ("icrl_walker", "walker", -3.0, "behind"), ("icrl_pendulum", "pendulum", -0.015, "behind"),
    ("icrl_swimmer", "swimmer", 0.5, "infront")])
def test_icrl_envs_truth_coordinate_and_hidden_cost(name, task, wall, side):
    pytest.importorskip("mujoco")
    from pbicrl.baselines.icl import icl_env
    from pbicrl.experiments.icrl_benchmark import make_task_env

    spec = icl_env(name)
    assert spec.side == side and spec.true_location == wall
    # the benchmark's strict indicator on the post-step x: beyond the wall violates, the wall itself does not
    probe = np.array([1.5, 1.0001, 1.0, 0.9667, 0.0, -8 / 3]) * wall
    assert spec.true_indicator(probe).tolist() == [1, 1, 0, 0, 0, 0]
    # the CMSE grid runs from the start (0) to twice the wall, the wall in the middle
    assert sorted((spec.grid[0, 0], spec.grid[-1, 0])) == sorted((2 * wall, 0.0))
    assert spec.true_indicator(spec.grid).mean() == pytest.approx(0.5, abs=0.01)
    assert spec.location_grid[0] == -5 * abs(wall) and spec.location_grid[-1] == 5 * abs(wall)
    # a hand-set state: the root moved behind the wall; the coordinate is the post-step obs[0], the cost is hidden
    for x0, violates in ((5 / 3 * wall, 1.0), (-2 / 3 * wall, 0.0)):
        env, ref = spec.make(), make_task_env(task)
        try:
            for e in (env, ref):
                e.reset(seed=0)
                u = e.unwrapped
                qpos = u.data.qpos.copy()
                qpos[0] = x0
                u.set_state(qpos, np.zeros_like(u.data.qvel))
            a = np.zeros(env.action_space.shape)
            obs, r, _, _, info = env.step(a)
            obs_ref, r_ref, _, _, info_ref = ref.step(a)
        finally:
            env.close()
            ref.close()
        c = spec.coord(obs, info)
        assert c.shape == (1,) and c[0] == obs[0] and abs(c[0] - x0) < abs(wall) / 30
        assert spec.true_indicator(c)[0] == violates == info_ref["cost"]
        assert "cost" not in info and r == r_ref  # the learner gets the nominal reward only, no true cost
    # the budgets are the robot's, the expert the good group of the shipped dataset (which never crosses)
    robot = task if task in ("halfcheetah", "ant") else "ant"  # the others have no ICL budgets of their own: Ant's
    assert icl_preset("default", name).to_dict() == icl_preset("default", robot).to_dict()
    expert = expert_coordinates(name, group=1, n=None)
    assert len(expert) == 100 and all(t.shape[1] == 1 for t in expert)
    assert max(spec.true_indicator(t).max() for t in expert) == 0.0


def test_location_of_a_wall_behind_is_scanned_down_from_the_demonstrations():
    from pbicrl.baselines.icl import icl_env
    from pbicrl.baselines.icl.run import _location

    pytest.importorskip("mujoco")
    spec = icl_env("icrl_halfcheetah")
    net = ConstraintNet(1, (1,), [0.0], [1.0])
    with torch.no_grad():  # c(x) >= 0.5 exactly where x <= -3.21: relu(-x - 3.2) * 100 - 1 >= 0
        net.mlp[0].weight.fill_(-1.0)
        net.mlp[0].bias.fill_(-3.2)
        net.mlp[2].weight.fill_(100.0)
        net.mlp[2].bias.fill_(-1.0)
    assert net.numpy(np.array([-3.3, -3.0, 5.0])).round(2).tolist() == [1.0, 0.27, 0.27]
    assert _location(net, spec, xmin=-2.77) == pytest.approx(-3.21, abs=0.02)
    assert _location(net, spec, xmin=-4.0) == -4.0  # already costed where the demonstrations are
    assert _location(ConstraintNet(1, (8,), [0.0], [1.0]), spec, xmin=-2.77) is None  # nowhere


def test_location_of_a_wall_in_front_is_scanned_up_from_the_nearest_approach():
    """The swimmer's demonstrations swim both ways (x from -0.84 to 0.4987): a net that also costs the far left,
    where they rarely go, must not put the wall in front at their lowest x."""
    from dataclasses import replace

    from pbicrl.baselines.icl import icl_env
    from pbicrl.baselines.icl.run import _location

    pytest.importorskip("mujoco")
    spec = icl_env("icrl_swimmer")
    assert spec.side == "infront" and spec.scan_from == "nearest"
    net = ConstraintNet(1, (2,), [0.0], [1.0])
    with torch.no_grad():  # c(x) >= 0.5 where x <= -0.7 or x >= 0.6: 100 relu(-x - 0.69) + 100 relu(x - 0.59) - 1
        net.mlp[0].weight.copy_(torch.tensor([[-1.0], [1.0]]))
        net.mlp[0].bias.copy_(torch.tensor([-0.69, -0.59]))
        net.mlp[2].weight.fill_(100.0)
        net.mlp[2].bias.fill_(-1.0)
    assert net.numpy(np.array([-0.8, 0.0, 0.7])).round(2).tolist() == [1.0, 0.27, 1.0]
    assert _location(net, spec, xmin=-0.84, xmax=0.4987) == pytest.approx(0.6, abs=0.01)
    lowest = replace(spec, scan_from="lowest")  # the project's in-front walls: from the demonstrations' start
    assert _location(net, lowest, xmin=-0.84, xmax=0.4987) == -0.84
    with pytest.raises(ValueError, match="xmax"):
        _location(net, spec, xmin=-0.84)
    with pytest.raises(ValueError, match="scan_from"):
        replace(spec, scan_from="far")
