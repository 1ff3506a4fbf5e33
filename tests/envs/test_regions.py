import numpy as np
import pytest

from pbicrl.envs.regions import Box, Disc, NavigationTask, label_group


def test_disc_open_and_closed_boundaries():
    open_disc = Disc((0.0, 0.0), 3.0)
    closed = Disc((0.0, 0.0), 3.0, closed=True)
    pts = np.array([[3.0, 0.0], [2.999, 0.0], [0.0, 3.0001]])
    assert open_disc.contains(pts).tolist() == [False, True, False]
    assert closed.contains(pts).tolist() == [True, True, False]
    np.testing.assert_allclose(open_disc.distance([[3.0, 4.0]]), [5.0])


def test_box_bounds_inclusive_and_validation():
    box = Box((0.0, 0.0, 0.0), (1.0, 2.0, 3.0))
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [1.0001, 1.0, 1.0], [0.5, 1.0, -0.1]])
    assert box.contains(pts).tolist() == [True, True, False, False]
    with pytest.raises(ValueError, match="low <= high"):
        Box((1.0,), (0.0,))
    with pytest.raises(ValueError, match="radius"):
        Disc((0.0,), 0.0)
    with pytest.raises(ValueError, match="states"):
        box.contains(np.zeros((2, 2)))


def test_label_group_red_dominates():
    assert label_group([0, 0], [0, 0]) == 1
    assert label_group([0, 1], [0, 0]) == 2
    assert label_group([1, 1], [0, 1]) == 3
    assert label_group([0, 0], [1, 0]) == 3


def test_task_weights_and_features():
    task = NavigationTask(goal=Disc((0.0, 0.0), 1.0, closed=True), orange=Disc((5.0, 0.0), 1.0),
                          red=Box((-6.0, -1.0), (-4.0, 1.0)), true_weights=(1, -2, -3, -4),
                          nominal_weights=(1, 0, 0, -4))
    f = task.features([[2.0, 0.0], [5.0, 0.5], [-5.0, 0.0], [0.0, 1.0]])
    np.testing.assert_allclose(f, [[0.5, 0, 0, 1], [1 / np.hypot(5, 0.5), 1, 0, 1], [0.2, 0, 1, 1], [1.0, 0, 0, 0]])
    np.testing.assert_allclose(task.weights("nominal"), [1, 0, 0, -4])
    np.testing.assert_allclose(task.weights([1, 2, 3, 4]), [1, 2, 3, 4])
    with pytest.raises(ValueError, match="reward_weights"):
        task.weights("bogus")
    with pytest.raises(ValueError, match="reward_weights"):
        task.weights([1, 2])
    assert np.isfinite(task.features([[0.0, 0.0]])).all()  # 1/d stays finite at the centre
    assert task.group([[2.0, 0.0], [5.0, 0.0], [-5.0, 0.0]]) == 3
