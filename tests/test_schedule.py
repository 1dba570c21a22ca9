"""The evaluation schedule and the iterations a run's final numbers average."""

import numpy as np

from emgail_jax.host.schedule import (
    FINAL_WINDOW,
    evaluation_plan,
    last_measured,
    measured_iterations,
    window_text,
)


def test_evaluation_plan_every_n_and_the_last_ten():
    # Iterations 1..30 of 30, every 10: 10, 20, and the last ten 21..30.
    plan = np.concatenate([evaluation_plan(first, 10, 30, 10) for first in (0, 10, 20)])
    np.testing.assert_array_equal(np.flatnonzero(plan) + 1, [10, 20, *range(21, 31)])
    # Every iteration with every=1; a short run evaluates throughout.
    assert evaluation_plan(0, 7, 400, 1).all()
    assert evaluation_plan(0, 5, 5, 10).all()
    # Iterations 391..397 of 397: 388..397 are the last ten, so all of them.
    assert evaluation_plan(390, 7, 397, 10).all()
    np.testing.assert_array_equal(np.flatnonzero(evaluation_plan(370, 10, 397, 10)) + 371, [380])


def test_the_schedule_evaluates_every_iteration_the_final_window_averages():
    """Over a whole run of 397 iterations (chunks of 10), the last measured iterations are
    exactly its last FINAL_WINDOW."""
    plan = np.concatenate(
        [evaluation_plan(first, min(10, 397 - first), 397, 10) for first in range(0, 397, 10)]
    )
    np.testing.assert_array_equal(last_measured(plan), np.arange(397 - FINAL_WINDOW, 397))


def test_last_measured_takes_the_last_ones_oldest_first():
    measured = np.zeros(40, bool)
    measured[9::10] = True  # 9, 19, 29, 39
    np.testing.assert_array_equal(last_measured(measured), [9, 19, 29, 39])
    np.testing.assert_array_equal(last_measured(measured, last=2), [29, 39])
    measured[25:] = True
    np.testing.assert_array_equal(last_measured(measured), np.arange(30, 40))
    assert len(last_measured(np.zeros(5, bool))) == 0


def test_measured_iterations_any_entry_not_nan():
    values = np.full((2, 3, 2), np.nan)
    values[0, 1, 0] = 1.0  # one entry of a [K] metric is enough
    values[1, 2] = 2.0
    np.testing.assert_array_equal(
        measured_iterations(values), [[False, True, False], [False, False, True]]
    )
    np.testing.assert_array_equal(measured_iterations(np.ones((1, 2))), [[True, True]])


def test_window_text():
    assert window_text(400) == "the last 10 of 400"
    assert window_text(10) == "all 10"
    assert window_text(3) == "all 3"
