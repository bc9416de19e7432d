"""The layered models against the Monte Carlo simulator (`fitlab simulate`) on small stacks:

* coated(rough_conductor) == the simulator's one-bounce component (max_bounces = 1, the coat's
  delta dropped) under a smooth absorbing coat: the coated model is the exact single-bounce,
  single-point solution there, so the difference is Monte Carlo noise;
* coated(lambertian) with interreflection=closed_form == the full simulation (every bounce).

The model is averaged over each detector cone with cos θo weights, as the simulator tallies
(``cone_average`` of benchmarks/layered_validation.py, which makes the full table).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from fitlab.simulate import simulate

_SPEC = importlib.util.spec_from_file_location(
    "layered_validation",
    Path(__file__).resolve().parents[2] / "benchmarks" / "layered_validation.py")
lv = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(lv)


def _check(res, values, sigma, model, floor=0.05, z=4.0, rel=0.03):
    keep = values > floor * values.max()
    assert keep.sum() >= 10
    dev = np.abs(model[keep] - values[keep])
    bound = z * sigma[keep] + rel * values[keep]
    assert np.all(dev <= bound), np.c_[res.theta_o[keep], res.phi_o[keep], values[keep],
                                       model[keep], sigma[keep]][dev > bound]


@pytest.mark.slow
def test_coated_conductor_equals_simulated_one_bounce():
    tau, a2 = 0.5, 0.2
    res = simulate(lv.scene(None, ("conductor", a2), tau, 1), samples=600_000, seed=3)
    params = {"coat_eta": lv.ETA, "coat_tau": tau, "alpha": a2, "n": lv.N_CR / lv.ETA,
              "k": lv.K_CR / lv.ETA}
    model = lv.cone_average("coated(rough_conductor)", params, {}, res.theta_o, res.phi_o)
    _check(res, res.by_order[1, :, 0], res.sigma_by_order[1, :, 0], model)
    # nothing else reaches the detectors with one bounce and the delta dropped
    assert np.allclose(res.by_order[1, :, 0], res.value[:, 0])


@pytest.mark.slow
def test_coated_lambertian_closed_form_equals_full_simulation():
    tau = 0.3
    res = simulate(lv.scene(None, 0.7, tau, "all"), samples=600_000, seed=4)
    params = {"coat_eta": lv.ETA, "coat_tau": tau, "albedo": 0.7}
    closed = lv.cone_average("coated(lambertian)", params, {"interreflection": "closed_form"},
                             res.theta_o, res.phi_o)
    _check(res, res.value[:, 0], res.sigma[:, 0], closed)
    single = lv.cone_average("coated(lambertian)", params, {"interreflection": "single"},
                             res.theta_o, res.phi_o)
    # the single-bounce default misses the inter-reflections: clearly below the simulation
    assert np.mean(single) < 0.92 * np.mean(res.value[:, 0])
