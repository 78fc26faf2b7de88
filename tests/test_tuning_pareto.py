"""Pareto masks and hypervolume against hand-computed values."""

import numpy as np
import pytest

from dcm.tuning.pareto import hypervolume, pareto_mask, reference_point


def test_pareto_mask_drops_dominated_points():
    points = np.array([[1.0, 3.0], [2.0, 2.0], [3.0, 1.0], [2.5, 2.5], [1.0, 3.0]])
    assert pareto_mask(points).tolist() == [True, True, True, False, False]


def test_hypervolume_of_a_staircase():
    points = np.array([[1.0, 3.0], [2.0, 2.0], [3.0, 1.0]])
    # reference (4, 4): boxes 3x1 + 2x1 + 1x1 above the staircase = 6
    assert hypervolume(points, np.array([4.0, 4.0])) == pytest.approx(6.0)
    assert hypervolume(points[:1], np.array([4.0, 4.0])) == pytest.approx(3.0)
    assert hypervolume(np.array([[5.0, 5.0]]), np.array([4.0, 4.0])) == 0.0


def test_reference_point_covers_every_set():
    ref = reference_point(np.array([[1.0, 4.0]]), np.array([[3.0, 2.0]]), margin=0.5)
    np.testing.assert_allclose(ref, [4.0, 5.0])
