"""Importance sampling of the layered models against their own pdf and eval (as
tests/models/test_sampling.py does for the single-layer models):

* χ² goodness of fit of the sampled directions against ``pdf`` (tests/chi2.py), Šidák-corrected
  over this module, at normal, oblique and grazing incidence, with absorption, total internal
  reflection between coats (n2 < n1), the narrow-lobe option and the three bases;
* weight == f|cos θo|/pdf and the returned pdf == pdf(wo), over grids of parameters and
  incidence angles (including incidence from below, which a BRDF never samples).
"""

from __future__ import annotations

import itertools
import zlib

import numpy as np
import pytest

from fitlab.models import get_model
from test_sampling import _direction, call, density, sampler

try:
    from chi2 import chi2_test, sidak_level, sidak_z
except ImportError:  # pragma: no cover
    from tests.chi2 import chi2_test, sidak_level, sidak_z

SIGNIFICANCE = 0.01
N_SAMPLES = 200_000

CONDUCTOR = {"alpha": 0.2, "n": 0.2, "k": 3.9}
WW_COND = {"alpha1": 0.1, "n1": 1.5, "k1": 0.0, "tau1": 0.2, "alpha2": 0.3, "n2": 3.84, "k2": 4.37}
WW3 = {"alpha1": 0.05, "n1": 2.0, "k1": 0.0, "tau1": 0.1, "alpha2": 0.3, "n2": 1.3, "k2": 0.0,
       "tau2": 0.2, "albedo3": 0.8, "sigma3": 0.4}

CHI2_CASES = [
    ("coated(lambertian)", {"coat_eta": 1.5, "coat_tau": 0.3, "albedo": 0.7}, {}, (0.0, 60.0, 88.0)),
    ("coated(rough_conductor)", {"coat_eta": 1.5, "coat_tau": 0.1, **CONDUCTOR}, {},
     (0.0, 45.0, 85.0)),
    ("coated(rough_conductor)", {"coat_eta": 2.5, "coat_tau": 0.0, **CONDUCTOR, "alpha": 0.03},
     {"distribution": "beckmann"}, (30.0,)),
    ("coated(lambertian,specular=lobe)",
     {"coat_eta": 1.5, "coat_tau": 0.3, "coat_alpha": 0.05, "albedo": 0.7}, {}, (0.0, 70.0)),
    ("weidlich_wilkie(rough_conductor)", WW_COND, {}, (0.0, 45.0, 85.0)),
    ("weidlich_wilkie(lambertian)", {"alpha1": 0.3, "n1": 1.5, "k1": 0.0, "tau1": 0.0,
                                     "albedo2": 0.9}, {"distribution": "beckmann"}, (30.0,)),
    ("weidlich_wilkie(oren_nayar,layers=3)", WW3, {}, (0.0, 60.0)),
]
#: The χ² tests of the Weidlich–Wilkie models compile their costliest kernels: whole suite only
#: (the quick tier keeps the coated models' and the registry contract's sampling-weight checks).
CASES = [pytest.param(name, params, opts, theta, id=f"{name}-{'-'.join(opts.values())}-{theta:g}",
                      marks=[pytest.mark.slow] if name.startswith("weidlich_wilkie") else [])
         for name, params, opts, thetas in CHI2_CASES for theta in thetas]
LEVEL = sidak_level(SIGNIFICANCE, len(CASES))
Z_MASS = sidak_z(SIGNIFICANCE, len(CASES))


@pytest.mark.parametrize("name, params, options, theta", CASES)
def test_chi2_sampling_matches_pdf(name, params, options, theta, request):
    opts = {**get_model(name).default_options(), **options}
    wi = _direction(theta)
    seed = zlib.crc32(request.node.callspec.id.encode())
    res = chi2_test(sampler(name, params, wi, opts), density(name, params, wi, opts),
                    N_SAMPLES, seed)
    print(res.report())
    assert res.quadrature_error * N_SAMPLES < 1.0, res.report()
    assert res.pdf_mass <= 1.0 + 1e-6, res.report()
    assert abs(res.pdf_mass - res.valid_fraction) <= Z_MASS * res.mass_sigma() + 1e-6, res.report()
    assert res.p_value >= LEVEL, f"rejected at Šidák level {LEVEL:.3g}: {res.report()}"


WEIGHT_GRIDS = {
    "coated(lambertian)": ({"coat_eta": (1.0, 1.0001, 1.5, 3.0), "coat_tau": (0.0, 2.0),
                            "albedo": (0.3, 1.0)}, {"interreflection": "closed_form"}),
    "coated(rough_conductor)": ({"coat_eta": (1.0, 1.5, 3.0), "coat_tau": (0.0, 2.0),
                                 "alpha": (0.01, 0.3, 1.0), "n": (0.2,), "k": (3.9,)}, {}),
    "coated(oren_nayar,specular=lobe)": ({"coat_eta": (1.0, 1.5), "coat_tau": (0.0, 2.0),
                                          "coat_alpha": (0.01, 0.5), "albedo": (0.6,),
                                          "sigma": (0.0, 1.0)}, {}),
    "weidlich_wilkie(rough_conductor)": ({"alpha1": (0.01, 0.5), "n1": (1.0, 1.5, 3.0),
                                          "k1": (0.0, 0.6), "tau1": (0.0, 2.0),
                                          "alpha2": (0.05, 1.0), "n2": (3.84,), "k2": (4.37,)},
                                         {"roughness_clamp": "clamp"}),
    "weidlich_wilkie(oren_nayar,layers=3)": (
        {"alpha1": (0.01, 0.5), "n1": (1.5, 2.4), "k1": (0.0,), "tau1": (0.0, 2.0),
         "alpha2": (0.1,), "n2": (1.2, 3.0), "k2": (0.0,), "tau2": (0.5,), "albedo3": (0.8,),
         "sigma3": (0.5,)}, {"distribution": "beckmann", "fresnel": "schlick"}),
}
THETAS = (0.0, 30.0, 60.0, 85.0, 89.9, 120.0)
PER_CONFIG = 64


#: The Weidlich–Wilkie grids are the costliest to compile: whole suite only (the registry-wide
#: contract, tests/models/test_model_contract.py, checks their sampling weights in the quick tier).
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow)
                                  if n.startswith("weidlich_wilkie") else n
                                  for n in WEIGHT_GRIDS])
def test_sample_weight_and_pdf_consistent(name):
    grid, options = WEIGHT_GRIDS[name]
    opts = {**get_model(name).default_options(), **options}
    combos = np.array(list(itertools.product(THETAS, *grid.values())))
    rng = np.random.default_rng(17)
    u = rng.random((len(combos), PER_CONFIG, 3))
    wi = np.repeat(_direction(combos[:, 0])[:, None, :], PER_CONFIG, axis=1).reshape(-1, 3)
    params = {k: np.repeat(combos[:, 1 + j], PER_CONFIG) for j, k in enumerate(grid)}
    u = u.reshape(-1, 3)
    wo, weight, pdf_s = call(name, "sample", opts, params, wi, u)
    f = call(name, "eval", opts, params, wi, wo)
    pdf_e = call(name, "pdf", opts, params, wi, wo)
    assert np.isfinite(wo).all() and np.isfinite(weight).all() and np.isfinite(pdf_s).all()
    valid = pdf_s > 0
    assert valid.mean() > 0.2
    assert np.all(weight[~valid] == 0.0)
    assert not np.any(valid & (wi[:, 2] <= 0)) and np.all(wo[valid, 2] > 0)
    np.testing.assert_allclose(np.linalg.norm(wo[valid], axis=-1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(pdf_e[valid], pdf_s[valid], rtol=1e-9)
    np.testing.assert_allclose(weight[valid], f[valid] * wo[valid, 2] / pdf_e[valid], rtol=1e-9)
