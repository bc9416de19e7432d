"""The losses' per-row constants (fitlab.fitting.losses.loss_weights)."""

from __future__ import annotations

import numpy as np
import pytest

from fitlab.fitting.losses import LOSSES, loss_weights


@pytest.mark.parametrize("loss", list(LOSSES))
def test_many_datasets_at_once_are_each_dataset_alone(loss):
    """Datasets on the same rows (rows on the last axis, as fit-maps passes its texels) get
    the constants each would get alone: the relative loss's floor is each dataset's own."""
    rng = np.random.default_rng(3)
    value = rng.uniform(0.0, 2.0, (5, 7)) * np.array([1, 10, 100, 1e-3, 1])[:, None]
    value[4] = 0.0  # a dataset of zeros: the floor's guard
    sigma = 0.1 * value + 0.01
    cos_o = rng.uniform(0.1, 1.0, 7)
    many = loss_weights(loss, value, sigma, cos_o)
    for b in range(5):
        one = loss_weights(loss, value[b], sigma[b], cos_o)
        for k, x in one.items():
            np.testing.assert_array_equal(np.broadcast_to(many[k], value.shape)[b], x)
