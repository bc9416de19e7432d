"""benchmarks/instrument_floor.py: the normal-incidence ring floor (an isotropic model predicts
one value per ring of fixed θo at θi = 0) is zero for isotropic readings and equals the closed
form for a known azimuthal modulation."""

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location(
    "instrument_floor", Path(__file__).resolve().parents[2] / "benchmarks" / "instrument_floor.py")
instrument_floor = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(instrument_floor)


def _rings(modulation):
    theta_o = np.repeat(np.arange(5.0, 90.0, 5.0), 36)
    phi_o = np.tile(np.arange(0.0, 360.0, 10.0), 17)
    base = 1.0 / np.cos(np.radians(theta_o)) ** 0.5
    value = base * (1.0 + modulation * np.cos(2.0 * np.radians(phi_o)))
    # a second incidence the ring floor must ignore
    return SimpleNamespace(channel=np.zeros(2 * value.size, int),
                           theta_i=np.concatenate([np.zeros(value.size), np.full(value.size, 40.0)]),
                           theta_o=np.concatenate([theta_o, theta_o]),
                           value=np.concatenate([value, 3.0 * value[::-1]]))


def test_isotropic_readings_have_no_ring_floor():
    rings, rel, vals, vmax = instrument_floor.normal_incidence_rings(_rings(0.0), 0)
    assert len(rings) == 17 and rel.size == 17 * 36
    assert np.max(np.abs(rel)) < 1e-12
    assert all(abs(r[2] - 1.0) < 1e-12 for r in rings)


def test_ring_floor_matches_the_best_constant_of_a_known_modulation():
    a = 0.2
    rings, rel, vals, vmax = instrument_floor.normal_incidence_rings(_rings(a), 0)
    f = 1.0 + a * np.cos(2.0 * np.radians(np.arange(0.0, 360.0, 10.0)))
    c = np.sum(1 / f) / np.sum(1 / f ** 2)
    expected = np.sqrt(np.mean((c / f - 1.0) ** 2))
    for to, n, ratio, err, mean in rings:
        assert n == 36
        assert ratio == pytest.approx((1 + a) / (1 - a), rel=1e-12)
        assert err == pytest.approx(expected, rel=1e-12)
    # the best constant beats the ring mean in the relative sense
    mean_err = np.sqrt(np.mean((np.mean(f) / f - 1.0) ** 2))
    assert expected < mean_err
