"""A run's history on the host: chunks appended, and the means of its last measured
iterations."""

import numpy as np

from emgail_jax.host.history import concat_history, final_means


def test_final_means_of_the_last_iterations():
    history = {
        "erd": np.array([np.arange(12.0), 10 * np.arange(12.0)]),  # [S=2, L=12]
        "returns": np.arange(2 * 12 * 2, dtype=float).reshape(2, 12, 2),
    }
    final = final_means(history)
    # Mean of 2..11 = 6.5.
    np.testing.assert_allclose(final["erd"], [6.5, 65.0])
    assert final["returns"].shape == (2, 2)
    # returns[s, l, k] = 24 s + 2 l + k: mean over l = 2..11 is 24 s + 13 + k.
    np.testing.assert_allclose(final["returns"], [[13, 14], [37, 38]])
    np.testing.assert_allclose(final_means(history, last=3)["erd"], [10.0, 100.0])
    short = {"erd": np.array([[1.0, 2.0, 6.0]])}
    np.testing.assert_allclose(final_means(short)["erd"], [3.0])


def test_final_means_average_the_last_measured_iterations():
    """Iterations without evaluation log NaN; the final value is the mean of the last ten that
    were measured, per seed."""
    erd = np.full((2, 40), np.nan)
    erd[:, 9::10] = 100.0  # iterations 10, 20, 30, 40
    erd[0, 28:] = np.arange(12.0)  # seed 0 measured in each of its last 12 iterations
    returns = np.repeat(erd[..., None], 3, -1)
    final = final_means({"erd": erd, "returns": returns})
    # Seed 0: the last ten measured are 2..11 -> 6.5; seed 1: 100 at 10, 20, 30, 40 -> 100.
    np.testing.assert_allclose(final["erd"], [6.5, 100.0])
    np.testing.assert_allclose(final["returns"], [[6.5] * 3, [100.0] * 3])


def test_final_means_keep_nan_for_a_metric_never_measured():
    final = final_means({"eval/cluster_accuracy": np.full((2, 12), np.nan)})
    assert final["eval/cluster_accuracy"].shape == (2,)
    assert np.all(np.isnan(final["eval/cluster_accuracy"]))


def test_final_means_are_float64_means_of_float32_logs():
    """The logged metrics are float32; their means are taken in float64, as summaries hold."""
    values = np.float32([[0.1, 0.2, 0.3]])
    final = final_means({"x": values})
    assert final["x"].dtype == np.float64
    assert final["x"][0] == values.astype(np.float64).mean()


def test_concat_history_appends_along_iterations():
    first = {"a": np.zeros((2, 3)), "b": np.zeros((2, 3, 4))}
    history = concat_history(None, first)
    assert history is not first and history.keys() == first.keys()
    second = {"a": np.ones((2, 2)), "b": np.ones((2, 2, 4))}
    history = concat_history(history, second)
    assert history["a"].shape == (2, 5) and history["b"].shape == (2, 5, 4)
    np.testing.assert_array_equal(history["a"][0], [0, 0, 0, 1, 1])
