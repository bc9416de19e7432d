"""Least-squares kernels are compiled for a ladder of row counts (least_squares.padded_size), the
extra rows masked out: fits of one structure with different row counts share a compilation,
and the padding changes nothing a fit reports."""

from __future__ import annotations

import numpy as np

import fitlab
from fitlab.fitting import least_squares as lsq
from fitlab.fitting.channel import prepare_channel
from fitlab.io.directions import degrees_to_direction
from fitlab.io.measurement import Measurement


def test_ladder_covers_every_count_with_bounded_overhead():
    sizes = [lsq.padded_size(n) for n in range(1, 20001)]
    assert all(s >= n for n, s in zip(range(1, 20001), sizes))
    assert all(b >= a for a, b in zip(sizes, sizes[1:]))  # monotone
    assert all(s % 8 == 0 for s in sizes)
    assert all(s <= 1.19 * n + 8 for n, s in zip(range(1, 20001), sizes) if n > lsq.PAD_MIN_ROWS)
    assert len(set(sizes)) < 40  # few rungs: that is the point


def _measurement(n_o: int, seed: int) -> Measurement:
    """A synthetic rough-conductor BRDF, 2% noise, at two incidences and n_o outgoing angles."""
    rng = np.random.default_rng(seed)
    ti = np.repeat([20.0, 50.0], n_o)
    to = np.tile(np.linspace(0.0, 80.0, n_o), 2)
    po = np.zeros_like(to)
    wi = degrees_to_direction(ti, np.zeros_like(ti))
    wo = degrees_to_direction(to, po)
    f = np.asarray(fitlab.eval_bsdf("rough_conductor", {"alpha": 0.3, "n": 1.2, "k": 2.6}, wi,
                                    wo))
    v = f * np.exp(0.02 * rng.standard_normal(f.shape))
    n = len(v)
    return Measurement(path="<synthetic>", sha256="0" * 64, theta_i=ti, phi_i=np.zeros(n),
                       theta_o=to, phi_o=po, wi=wi, wo=wo, value=v, sigma=None,
                       channel=np.zeros(n, dtype=int), channel_names=("Y",), wavelength_nm=None,
                       quantity="bsdf", file_quantity="bsdf", metadata={}, lines=np.arange(n))


def _prepared(m):
    return prepare_channel(m, "rough_conductor", rows=np.ones(len(m.value), bool),
                           fix={"k": 2.6})


def test_padding_leaves_cost_gradient_and_residuals_unchanged():
    p = _prepared(_measurement(57, seed=1))
    space, data, loss = p["space"], p["data"], p["loss"]
    padded = lsq.pad_rows(space.static, data)
    assert padded.value.shape[0] == lsq.padded_size(114) > 114
    k = lsq.kernels(space.static, loss)
    u = np.array([0.3, 0.6])
    plain = np.asarray(k["value_and_grad"](u, lsq.problem_of(space, data)))
    pad = np.asarray(k["value_and_grad"](u, lsq.problem_of(space, padded)))
    np.testing.assert_allclose(pad, plain, rtol=1e-12, atol=0)
    r = np.asarray(lsq.residuals_unit(space.static, loss, u, lsq.problem_of(space, padded)))
    assert np.all(r[114:] == 0)


def test_fits_of_one_structure_with_different_row_counts_share_the_compilation():
    fits = []
    before = set(lsq._compiled_local)
    for n_o, seed in ((50, 2), (55, 3)):  # 100 and 110 rows: one rung (112)
        p = _prepared(_measurement(n_o, seed))
        ls = lsq.fit_least_squares(p["space"], p["data"], p["loss"],
                                   start_native=p["start_native"])
        assert ls.residuals.shape == (2 * n_o,) and ls.jacobian.shape == (2 * n_o, 2)
        assert ls.dof == 2 * n_o - 2
        fits.append(ls)
    added = set(lsq._compiled_local) - before
    assert len(added) == 1, added  # the second fit reused the first one's local stage
    for ls in fits:
        alpha, n = ls.native
        assert abs(alpha - 0.3) < 4 * ls.stderr[0] + 0.01 and abs(n - 1.2) < 4 * ls.stderr[1] + 0.05


def test_api_fit_is_the_optimum_of_the_rows_given():
    """The padded fit's optimum is not beaten by the unpadded cost function anywhere near it
    (106 rows: the rung of the fits above, so no new compilation of the local stage)."""
    m = _measurement(53, seed=4)
    r = fitlab.fit(m, "rough_conductor", fix={"k": 2.6}, bootstrap=0)
    p = _prepared(m)
    space, data, loss = p["space"], p["data"], p["loss"]
    k = lsq.kernels(space.static, loss)
    problem = lsq.problem_of(space, data)  # unpadded
    best = np.array([r.parameters["Y"][name] for name in space.names])
    u0 = space.to_unit(best)
    c0 = float(k["value"](u0, problem))
    for du in (np.array([1e-4, 0]), np.array([0, 1e-4]), np.array([-1e-4, 1e-4])):
        assert float(k["value"](u0 + du, problem)) >= c0 * (1 - 1e-9)


def test_scan_blocks_count_a_models_per_call_samples():
    """A model that tabulates per call (SpongeCake's energy budget) declares the samples it
    draws per parameter set, sums and derived models inherit them, and the global scan sizes
    its blocks by rows + those samples (a two-layer lobe fit's 4,096-point scan asked for 40 GB
    in one block before)."""
    from fitlab.fitting.least_squares import scan_block
    from fitlab.fitting.searches import SCAN_BLOCK
    from fitlab.models import get_model
    from fitlab.models.base import call_work

    plain, lobe = get_model("rough_conductor"), get_model("spongecake(fiber,surface,multiple=only)")
    assert call_work(plain) == 0 and call_work(lobe) > 10_000
    assert call_work(get_model("spongecake(fiber,multiple=learned)")) \
        == call_work(get_model("spongecake(fiber,multiple=lobe)")) > 0
    assert call_work(get_model("lambertian+spongecake(fiber,multiple=lobe)")) \
        == call_work(get_model("spongecake(fiber,multiple=lobe)"))
    assert scan_block(4096, 256, plain) == 4096
    n = scan_block(4096, 256, lobe)
    assert 1 <= n < 4096 and n * (256 + call_work(lobe)) <= SCAN_BLOCK
