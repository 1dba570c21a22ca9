"""What the variants attach to the normalised batch: termination flags and AIRL's successors,
their shapes checked and their per-sample arrays grown with the batch."""

import jax
import numpy as np
import pytest

from emgail_jax.variants.extras import Extras, attached, extras_of, more_samples


@pytest.mark.parametrize(
    "broken",
    [
        # termination flags of fewer samples, or of fewer pairs
        dict(terminal=np.zeros((3, 3)), expert_terminal=np.zeros(6)),
        dict(terminal=np.zeros((3, 4)), expert_terminal=np.zeros(5)),
        # AIRL's successors without the continuation flag
        dict(successor=np.zeros((3, 4, 2)), expert_successor=np.zeros((6, 2))),
    ],
)
def test_extras_with_mismatched_shapes_are_refused(broken, random_batch):
    with pytest.raises(AssertionError):
        attached(random_batch(k=3, m=4, n=6, obs_dim=2), **broken).check()


def test_consistent_extras_pass_the_batchs_check(random_batch):
    batch = attached(
        random_batch(k=3, m=4, n=6, obs_dim=2),
        terminal=np.zeros((3, 4)),
        expert_terminal=np.zeros(6),
        successor=np.ones((3, 4, 3)),
        expert_successor=np.ones((6, 3)),
    )
    assert batch.check() is batch
    assert extras_of(random_batch()) == Extras()


@pytest.mark.parametrize("jit", [False, True])
def test_termination_flags_follow_their_samples(random_batch, jit):
    """Further negatives bring their termination flags where the batch keeps flags."""
    batch = random_batch(k=3, m=4, n=6, obs_dim=2)
    more_obs, more_executed = np.full((3, 2, 2), 7.0), np.full((3, 2, 1), 8.0)
    flagged = attached(batch, terminal=np.ones((3, 4)), expert_terminal=np.zeros(6))
    append = lambda b: more_samples(b, more_obs, more_executed, np.zeros((3, 2)))
    out = (jax.jit(append) if jit else append)(flagged)
    assert out.check() is out
    np.testing.assert_array_equal(out.extra.terminal, np.repeat([[1.0] * 4 + [0.0] * 2], 3, 0))
    # A batch without flags keeps none.
    assert more_samples(batch, more_obs, more_executed, np.zeros((3, 2))).extra is None
