"""fitlab.fresnel.fresnel_dielectric: the one dielectric Fresnel term, returning what a refraction
needs (Mitsuba 3's ``fresnel(cos_theta_i, eta) -> (r, cos_theta_t, eta_it, eta_ti)``).

Sources of the reference values, written next to each test:

* the textbook amplitude coefficients (Hecht, "Optics", eqs 4.42-4.43 / Born & Wolf 1.5.2)
  r_s = (cos θi - n cos θt)/(cos θi + n cos θt), r_p = (n cos θi - cos θt)/(n cos θi + cos θt),
  F = (r_s² + r_p²)/2, with cos θt from Snell's law sin θt = sin θi / n, in plain NumPy;
* closed forms at normal incidence ((n-1)/(n+1))², at grazing incidence (F = 1) and under total
  internal reflection (F = 1);
* the pre-refactor code of ``fresnel_dielectric_Walter2007`` (Walter eq. 22), transcribed below;
* Mitsuba 3's ``mi.fresnel`` (scalar_rgb, float32) where it is installed.

Contract: float32 and float64, n-d shapes, under jit and vmap, finite gradients at the special
points (critical angle, grazing, normal incidence, η = 1), NaN in -> NaN out.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.frame import refract
from fitlab.fresnel import cos_theta_critical, fresnel_dielectric, fresnel_dielectric_Walter2007
from fitlab.interface import refract_down, refract_up

#: η_t/η_i on both sides of 1, near 1 included.
ETAS = (1.0 + 1e-6, 1.0001, 1.05, 1.33, 1.5, 2.4, 5.0, 1 / 1.0001, 1 / 1.05, 1 / 1.33, 1 / 1.5,
        1 / 2.4, 0.2)
#: cos θi from normal to grazing incidence, grazing included.
COS = np.concatenate([[1.0, 1.0 - 1e-12, 0.999, 0.9], np.linspace(0.8, 0.05, 16),
                      [0.01, 1e-4, 1e-8, 0.0]])


def _hecht(cos_i, n):
    """(F, cos θt) from the textbook amplitude coefficients; F = 1, cos θt = 0 under total
    internal reflection (sin θt > 1)."""
    cos_i = np.asarray(cos_i, float)
    sin_t = np.sqrt(1.0 - cos_i**2) / n
    tir = sin_t >= 1.0
    cos_t = np.sqrt(np.maximum(1.0 - sin_t**2, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
        rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    F = np.where(tir, 1.0, 0.5 * (rs**2 + rp**2))
    return np.where(np.isnan(F), 1.0, F), np.where(tir, 0.0, cos_t)  # 0/0 at cos = 0, n = 1


def _walter2007_before(cos_i, eta):
    """fresnel_dielectric_Walter2007 as it was before fresnel_dielectric existed (Walter eq. 22)."""
    c = jnp.abs(cos_i)
    g2 = eta**2 - 1.0 + c**2
    tir = g2 <= 0
    g = jnp.where(g2 > 0, jnp.sqrt(jnp.where(g2 > 0, g2, 1.0)), 0.0)
    den_a, den_b = g + c, c * (g - c) + 1.0
    a = jnp.where(den_a != 0, (g - c) / jnp.where(den_a != 0, den_a, 1.0), 0.0)
    b = jnp.where(den_b != 0, (c * (g + c) - 1.0) / jnp.where(den_b != 0, den_b, 1.0), 0.0)
    F = 0.5 * a**2 * (1.0 + b**2)
    return jnp.where(tir, 1.0, jnp.clip(F, 0.0, 1.0))


_fd = jax.jit(fresnel_dielectric)


def _grid(dtype=jnp.float64):
    c, e = np.meshgrid(COS, ETAS, indexing="ij")
    return jnp.asarray(c, dtype), jnp.asarray(e, dtype)


def test_matches_the_textbook_amplitude_coefficients_and_snell():
    c, e = _grid()
    F, cos_t, eta_it, eta_ti = _fd(c, e)
    F_ref, cos_ref = _hecht(np.asarray(c), np.asarray(e))
    np.testing.assert_allclose(np.asarray(F), F_ref, rtol=1e-9, atol=1e-13)
    # incidence from outside: the transmitted direction points below, cos θt <= 0
    assert np.all(np.asarray(cos_t) <= 0)
    np.testing.assert_allclose(-np.asarray(cos_t), cos_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(eta_it), np.asarray(e))
    np.testing.assert_allclose(np.asarray(eta_ti), 1.0 / np.asarray(e), rtol=1e-15)
    # Snell: η_i sin θi = η_t sin θt wherever light is transmitted (sin from 1 - cos², whose
    # cancellation near the normal limits the absolute agreement to about 1e-9)
    ok = np.asarray(cos_t) < 0
    sin_i = np.sqrt(1.0 - np.asarray(c) ** 2)
    sin_t = np.sqrt(1.0 - np.asarray(cos_t) ** 2)
    np.testing.assert_allclose((np.asarray(eta_it) * sin_t)[ok], sin_i[ok], rtol=1e-9, atol=2e-9)


@pytest.mark.parametrize("eta", [1.5, 1.33, 2.4, 1 / 1.5, 1.0001])
def test_normal_incidence(eta):
    # ((η - 1)/(η + 1))²: Walter's 0.04 for glass (η = 1.5)
    F, cos_t, _, _ = _fd(jnp.float64(1.0), jnp.float64(eta))
    assert float(F) == pytest.approx(((eta - 1) / (eta + 1)) ** 2, rel=1e-12)
    assert float(cos_t) == pytest.approx(-1.0, abs=1e-15)


def test_glass_value():
    assert float(_fd(jnp.float64(1.0), jnp.float64(1.5))[0]) == pytest.approx(0.04, rel=1e-12)


@pytest.mark.parametrize("eta", [1 / 1.5, 1 / 1.33, 0.2, 1 / 1.0001])
def test_total_internal_reflection_gives_one_and_no_transmitted_direction(eta):
    c_crit = np.sqrt(1.0 - eta**2)  # sin θc = η
    c = jnp.asarray(np.array([0.0, 1e-9, 0.5 * c_crit, 0.999 * c_crit, c_crit]))
    F, cos_t, _, _ = _fd(c, jnp.full_like(c, eta))
    np.testing.assert_array_equal(np.asarray(F)[:-1], 1.0)
    np.testing.assert_array_equal(np.asarray(cos_t)[:-1], 0.0)
    assert float(F[-1]) == pytest.approx(1.0, abs=1e-6)  # continuous at the critical angle
    assert abs(float(cos_t[-1])) < 1e-6
    assert float(cos_theta_critical(jnp.float64(eta))) == pytest.approx(c_crit, rel=1e-14)
    # just above the critical angle light is transmitted again
    F2, cos_t2, _, _ = _fd(jnp.float64(min(1.0, c_crit * 1.001 + 1e-9)), jnp.float64(eta))
    assert float(F2) < 1.0 and float(cos_t2) < 0


def test_critical_cosine_is_zero_without_total_internal_reflection():
    e = jnp.asarray([1.0, 1.0001, 1.5, 5.0])
    np.testing.assert_array_equal(np.asarray(cos_theta_critical(e)), 0.0)


@pytest.mark.parametrize("eta", [1.0001, 1.33, 1.5, 5.0])
def test_grazing_incidence(eta):
    # cos θi = 0: everything is reflected, the refracted ray leaves at the critical angle
    F, cos_t, _, _ = _fd(jnp.float64(0.0), jnp.float64(eta))
    assert float(F) == 1.0
    assert float(cos_t) == pytest.approx(-np.sqrt(1.0 - 1.0 / eta**2), rel=1e-12)


@pytest.mark.parametrize("c", [1.0, 0.7, 0.2, 1e-3])
def test_index_matched_limit(c):
    # η -> 1: no reflection, the ray goes straight on (F = 0, cos θt = -cos θi at η = 1; near
    # grazing F rises to 1 over |η - 1| ~ cos²θi, as in the textbook formula)
    for eta in (1.0, 1.0 + 1e-9, 1.0 - 1e-9):
        F, cos_t, _, _ = _fd(jnp.float64(c), jnp.float64(eta))
        F_ref, cos_ref = _hecht(c, eta)
        assert float(F) == pytest.approx(float(F_ref), rel=1e-5, abs=1e-15)
        assert float(cos_t) == pytest.approx(-float(cos_ref), rel=1e-9)
        assert float(cos_t) == pytest.approx(-c, abs=2e-6)
    assert float(_fd(jnp.float64(c), jnp.float64(1.0))[0]) == 0.0


def test_incidence_from_inside_uses_the_reciprocal_index():
    c, e = _grid()
    F_out, cos_out, it_out, ti_out = _fd(c, 1.0 / e)
    F_in, cos_in, it_in, ti_in = _fd(-c, e)
    # cos θi = 0 counts as outside (Mitsuba's cos_theta_i >= 0): compare strictly inside only
    inside = np.asarray(c) > 0
    np.testing.assert_allclose(np.asarray(F_in)[inside], np.asarray(F_out)[inside], rtol=1e-12,
                               atol=1e-15)
    np.testing.assert_allclose(np.asarray(cos_in)[inside], -np.asarray(cos_out)[inside],
                               rtol=1e-12, atol=1e-15)
    assert np.all(np.asarray(cos_in)[inside] >= 0)  # transmitted upward
    np.testing.assert_allclose(np.asarray(it_in)[inside], 1.0 / np.asarray(e)[inside], rtol=1e-15)
    np.testing.assert_array_equal(np.asarray(ti_in)[inside], np.asarray(e)[inside])


def test_reflectance_is_the_same_along_a_refracted_pair():
    # Stokes: F(θi, η) = F(θt, 1/η) for the refracted cosine
    c = jnp.asarray(np.linspace(0.05, 1.0, 20))
    for eta in (1.33, 1.5, 2.4):
        F, cos_t, _, _ = _fd(c, jnp.full_like(c, eta))
        F_back, cos_back, _, _ = _fd(cos_t, jnp.full_like(c, eta))  # from inside, back up
        np.testing.assert_allclose(np.asarray(F_back), np.asarray(F), rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(np.asarray(cos_back), np.asarray(c), rtol=1e-10)


def test_F_is_the_previous_formula_and_walter2007_is_its_F():
    c, e = _grid()
    c = jnp.concatenate([c, -c])  # Walter2007 takes |cos_i|
    e = jnp.concatenate([e, e])
    before = np.asarray(jax.jit(_walter2007_before)(c, e))
    np.testing.assert_array_equal(np.asarray(jax.jit(fresnel_dielectric_Walter2007)(c, e)), before)
    np.testing.assert_array_equal(np.asarray(_fd(jnp.abs(c), e)[0]), before)


def test_float32_and_float64(dtype):
    c, e = _grid(dtype)
    out = _fd(c, e)
    for x in out:
        assert x.dtype == dtype and x.shape == c.shape
        assert np.all(np.isfinite(np.asarray(x)))
    # against float64 at the same (rounded) inputs; cos θt = sqrt(η² - sin²θi)/η loses digits
    # where η² - sin²θi cancels (near grazing incidence with η ≈ 1, near the critical angle)
    F64, cos64, _, _ = _fd(jnp.asarray(c, jnp.float64), jnp.asarray(e, jnp.float64))
    tol = 2e-6 if dtype == jnp.float32 else 1e-14
    np.testing.assert_allclose(np.asarray(out[0], float), np.asarray(F64), atol=tol)
    scale = np.maximum(np.abs(np.asarray(cos64)), 1e-2)
    assert np.all(np.abs(np.asarray(out[1], float) - np.asarray(cos64)) <= tol / scale)
    # inside, too
    out_in = _fd(-c, e)
    assert all(x.dtype == dtype for x in out_in)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in out_in)


def test_shapes_jit_vmap_and_nan():
    c = jnp.asarray(np.linspace(-1, 1, 24).reshape(2, 3, 4))
    F, cos_t, eta_it, eta_ti = fresnel_dielectric(c, 1.5)  # scalar η broadcasts
    assert F.shape == cos_t.shape == eta_it.shape == eta_ti.shape == (2, 3, 4)
    vm = jax.vmap(fresnel_dielectric, in_axes=(0, None))(c.reshape(-1), jnp.float64(1.5))
    for a, b in zip(vm, (F, cos_t, eta_it, eta_ti)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b).reshape(-1), rtol=1e-15)
    F_nan, cos_nan, _, _ = _fd(jnp.asarray([np.nan, 0.5, 0.1]), jnp.asarray([1.5, np.nan, np.nan]))
    assert np.all(np.isnan(np.asarray(F_nan))) and np.all(np.isnan(np.asarray(cos_nan)))


@pytest.mark.parametrize("c,eta", [
    (1.0, 1.5), (0.0, 1.5), (0.5, 1.0), (0.0, 1.0), (1.0, 1.0),
    (float(np.sqrt(1 - (1 / 1.5) ** 2)), 1 / 1.5),  # exactly at the critical angle
    (0.3, 1 / 1.5),  # total internal reflection
    (-0.4, 1.5), (-0.9, 1.5),  # from inside: TIR and transmission
    (1e-9, 1.0001), (0.7, 0.2),
])
def test_gradients_are_finite(c, eta, dtype):
    def total(ci, e):
        F, cos_t, eta_it, eta_ti = fresnel_dielectric(ci, e)
        return F + cos_t + eta_it + eta_ti

    g = jax.jit(jax.grad(total, argnums=(0, 1)))(jnp.asarray(c, dtype), jnp.asarray(eta, dtype))
    assert all(np.isfinite(float(x)) for x in g), g


def test_gradient_matches_finite_differences():
    def cos_t(e, c):
        return fresnel_dielectric(c, e)[1]

    for c, eta in ((0.6, 1.5), (0.9, 1 / 1.33), (-0.95, 1.5)):
        g = float(jax.grad(cos_t)(jnp.float64(eta), jnp.float64(c)))
        h = 1e-6
        fd = (float(cos_t(jnp.float64(eta + h), jnp.float64(c)))
              - float(cos_t(jnp.float64(eta - h), jnp.float64(c)))) / (2 * h)
        assert g == pytest.approx(fd, rel=1e-6)


def test_refractions_use_its_cos_theta_t():
    rng = np.random.default_rng(3)
    w = rng.normal(size=(64, 3))
    w[:, 2] = np.abs(w[:, 2])
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    w = jnp.asarray(w)
    for eta in (1.5, 1 / 1.5):
        e = jnp.full((64,), eta)
        _, cos_t, _, eta_ti = fresnel_dielectric(w[:, 2], e)
        # through the macro normal: frame.refract, interface.refract_down / refract_up
        wt, ok = refract(w, jnp.asarray([0.0, 0.0, 1.0]), e)
        np.testing.assert_array_equal(np.asarray(ok), np.asarray(cos_t) < 0)
        np.testing.assert_allclose(np.asarray(wt[:, 2])[np.asarray(ok)],
                                   np.asarray(cos_t)[np.asarray(ok)], rtol=1e-12)
        np.testing.assert_allclose(np.asarray(jnp.linalg.norm(wt, axis=-1))[np.asarray(ok)], 1.0,
                                   rtol=1e-12)
        wp, ok_d = refract_down(w, e)
        np.testing.assert_array_equal(np.asarray(ok_d), np.asarray(cos_t) < 0)
        np.testing.assert_allclose(np.asarray(wp[:, 2]), -np.asarray(cos_t), rtol=1e-12)
        np.testing.assert_allclose(np.asarray(wp[:, :2]), np.asarray(w[:, :2]) / eta, rtol=1e-12)
        back, ok_u = refract_up(wp, e)
        sel = np.asarray(ok_d & ok_u)
        np.testing.assert_allclose(np.asarray(back)[sel], np.asarray(w)[sel], rtol=1e-10,
                                   atol=1e-12)


@pytest.mark.mitsuba
def test_agrees_with_mitsuba(mitsuba_scalar):
    mi = mitsuba_scalar
    for eta in ETAS:
        for c in np.concatenate([COS, -COS[:-1]]):
            # Mitsuba's scalar variant is float32: compare at the float32 inputs
            c32, eta32 = float(np.float32(c)), float(np.float32(eta))
            r, cos_t, eta_it, eta_ti = mi.fresnel(c32, eta32)
            F, ct, it, ti = (float(x) for x in _fd(jnp.float64(c32), jnp.float64(eta32)))
            if 0 < abs(ct) < 1e-2:
                continue  # float32 cos²θt = 1 - η_ti² sin²θi is ill-conditioned there
            # Mitsuba's float32 cos²θt carries an absolute error near 1e-7, amplified by
            # 1/|cos θt| in cos θt and by about 1/cos²θt in F
            tol = 1e-7 / max(ct * ct, 1e-4)
            assert F == pytest.approx(r, abs=2e-6 + tol), (c, eta)
            assert ct == pytest.approx(cos_t, abs=2e-6 + tol), (c, eta)
            assert it == pytest.approx(eta_it, rel=1e-6) and ti == pytest.approx(eta_ti,
                                                                               rel=1e-6)


# ----------------------------------------------------------------------------------------------
# Conductor Fresnel with n < 1 (fitlab.fresnel.fresnel_conductor_exact)
# ----------------------------------------------------------------------------------------------


def _conductor_reference(c, n, k):
    """Textbook complex-index amplitudes (Born & Wolf 13.2) in NumPy complex128:
    F = (|r_s|² + |r_p|²)/2 with η = n + ik, cos θt = sqrt(1 - sin²θi/η²)."""
    eta = n + 1j * k
    ct = np.sqrt(1 - (1 - c * c) / eta**2 + 0j)
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)


def test_conductor_below_the_critical_angle_of_n_below_one():
    """n < 1 with small k: below the critical angle a = Re sqrt(η² - sin²θi) is nearly 0 and
    was the difference of two nearly equal numbers. Under jit with the half vector computed in
    the same graph, XLA's copies of it inside safe_sqrt's two where's once disagreed on its
    sign (F = 0 instead of 1 on the rows below, from a fit that strayed to n = 0.013, k = 0).
    Reference: the complex amplitude coefficients."""
    from fitlab.fresnel import fresnel_conductor_exact
    from fitlab.frame import dot, normalize

    wi = np.array([[0.8660254037844387, 0.0, 0.5], [0.8660254037844387, 0.0, 0.5],
                   [0.5, 0.0, 0.8660254037844387]])
    wo = np.array([[-0.6946583704589973, 8.507111497940214e-17, 0.7193398003386512],
                   [-0.6691306063588582, 8.194486549419928e-17, 0.7431448254773942],
                   [-0.7431448254773942, 9.100899319900706e-17, 0.6691306063588582]])

    def F(n, wi, wo):
        return fresnel_conductor_exact(dot(wi, normalize(wi + wo)), n, 0.0)

    def value_and_jacobian(n, wi, wo):
        return jax.jvp(lambda x: F(x, wi, wo), (n,), (jnp.ones_like(n),))

    n = jnp.float64(0.0132307957)
    np.testing.assert_array_equal(np.asarray(jax.jit(value_and_jacobian)(n, wi, wo)[0]), 1.0)
    np.testing.assert_array_equal(np.asarray(jax.jit(F)(n, wi, wo)), 1.0)
    c = np.linspace(0.0, 1.0, 201)
    for nn in (0.0132, 0.2, 0.5, 0.9, 1.0, 1.5):
        for k in (0.0, 1e-3, 0.05, 0.5, 3.9):
            got = np.asarray(jax.jit(fresnel_conductor_exact)(c, nn, k))
            want = _conductor_reference(c, nn, k)
            ok = np.isfinite(want)  # the amplitudes are 0/0 at grazing incidence for η = 1
            np.testing.assert_allclose(got[ok], want[ok], rtol=1e-9, atol=1e-12,
                                       err_msg=f"n={nn}, k={k}")
