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
from fitlab.fresnel import (cos_theta_critical, fresnel_dielectric, fresnel_dielectric_Schlick,
                            fresnel_dielectric_Walter2007)
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


# ----------------------------------------------------------------------------------------------
# Schlick for dielectrics (fitlab.fresnel.fresnel_dielectric_Schlick, rough_dielectric's
# ``fresnel=schlick``) and Lazányi–Szirmay-Kalos for metals
# ----------------------------------------------------------------------------------------------

_schlick_d = jax.jit(fresnel_dielectric_Schlick)


def _naive_schlick(c, eta):
    """Schlick's polynomial of the incident cosine whatever the side: wrong from the denser
    side beyond the critical angle."""
    f0 = ((eta - 1) / (eta + 1)) ** 2
    return f0 + (1 - f0) * (1 - np.abs(c)) ** 5


def test_schlick_dielectric_equals_exact_at_normal_incidence_and_grazing():
    """F(1) = ((η-1)/(η+1))² for either side (η and 1/η), like Walter eq. 22; F(0) = 1 from the
    less dense side. From the less dense side it is Schlick's polynomial of cos θi."""
    for eta in ETAS:
        assert float(_schlick_d(1.0, eta)) == pytest.approx(float(_fd(1.0, eta)[0]), rel=1e-12)
        if eta >= 1:
            assert float(_schlick_d(0.0, eta)) == 1.0
            np.testing.assert_allclose(np.asarray(_schlick_d(COS, eta)), _naive_schlick(COS, eta),
                                       rtol=1e-14, atol=0)


@pytest.mark.parametrize("eta", [1 / 1.5, 1 / 1.33, 0.2])
def test_schlick_dielectric_total_internal_reflection_and_the_reverse_crossing(eta):
    """From the denser side (η_t/η_i < 1) Schlick takes the transmitted cosine: F = 1 beyond the
    critical angle (where the incident cosine's polynomial is far below 1), continuous at it, and
    on a refracted pair the reflectance equals that of the reverse crossing (Snell's law)."""
    c_crit = float(np.sqrt(1 - eta**2))
    beyond = np.linspace(0.0, c_crit * (1 - 1e-9), 50)
    np.testing.assert_array_equal(np.asarray(_schlick_d(beyond, eta)), 1.0)
    assert np.all(_naive_schlick(beyond[1:], eta) < 0.95)  # what the fix avoids
    assert float(_schlick_d(c_crit * (1 + 1e-9), eta)) > 1 - 1e-3
    c_in = np.linspace(c_crit * 1.001, 1.0, 40)  # denser side, η_t/η_i = eta
    c_out = np.sqrt(1 - (1 - c_in**2) / eta**2)  # the same crossing seen from the other side
    np.testing.assert_allclose(np.asarray(_schlick_d(c_in, eta)),
                               np.asarray(_schlick_d(c_out, 1 / eta)), rtol=1e-11)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_schlick_dielectric_gradients_finite_and_dtype_kept(dtype):
    pts = [(1.0, 1.5), (0.0, 1.5), (0.0, 1.0), (1.0, 1.0), (0.0, 1 / 1.5),
           (float(np.sqrt(1 - 1 / 1.5**2)), 1 / 1.5), (0.5, 0.2), (1e-8, 1.0001)]
    c = jnp.asarray([p[0] for p in pts], dtype)
    e = jnp.asarray([p[1] for p in pts], dtype)
    assert _schlick_d(c, e).dtype == dtype
    g = jax.jit(jax.vmap(jax.grad(fresnel_dielectric_Schlick, argnums=(0, 1))))(c, e)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in g)
    assert np.isnan(float(_schlick_d(jnp.asarray(np.nan, dtype), jnp.asarray(1.5, dtype))))


def _rough_dielectric_schlick_checks(params, wi, wo, u):
    """One compiled call: f(i,o) and f(o,i) with fresnel=schlick (and exact), the sampler's
    weights and chosen sides with schlick."""
    from fitlab.models import get_model

    m = get_model("rough_dielectric")
    f_io = m.eval(params, wi, wo, fresnel="schlick")
    f_oi = m.eval(params, wo, wi, fresnel="schlick")
    f_exact = m.eval(params, wi, wo)
    wo_s, weight, _ = m.sample(params, wi, u, fresnel="schlick")
    return f_io, f_oi, f_exact, wo_s, weight


def test_rough_dielectric_schlick_reciprocity_r_plus_t_and_furnace():
    """rough_dielectric with fresnel=schlick (η = 1.5, both sides of the interface):
    normal-incidence reflection equals the exact model's; f(i,o) = f(o,i) in reflection and
    f(i,o)/η_o² = f(o,i)/η_i² in transmission (Walter eq. 21); with α = 1e-3 (G ≈ 1) the sampled
    reflected share is F_Schlick(θi) and reflected + transmitted = 1 (F and 1 - F per
    microfacet); with α = 0.5 the albedo (mean weight) is at most 1."""
    rng = np.random.default_rng(5)
    n_pairs, n_u = 1000, 4096
    thetas = np.radians([0.0, 45.0, 80.0, 180.0, 135.0, 120.0])  # from inside too
    def dirs(n):  # random directions on the sphere: either side for wi and wo
        v = rng.normal(size=(n, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)
    wi_r = np.concatenate([dirs(n_pairs), [[0.0, 0.0, 1.0]]])
    wo_r = np.concatenate([dirs(n_pairs), [[0.0, 0.0, 1.0]]])
    wi_s = np.repeat([[np.sin(t), 0.0, np.cos(t)] for t in thetas], n_u, axis=0)
    wi_s = np.concatenate([wi_s, wi_s])
    alpha = np.concatenate([np.full(len(thetas) * n_u, 1e-3), np.full(len(thetas) * n_u, 0.5)])
    n = len(wi_s)
    pad = n - len(wi_r)
    wi = np.concatenate([wi_r, np.repeat(wi_r[:1], pad, 0)])
    wo = np.concatenate([wo_r, np.repeat(wo_r[:1], pad, 0)])
    checks = jax.jit(_rough_dielectric_schlick_checks)  # one compilation: both calls pad to n rows
    f_io, f_oi, f_exact, _, _ = map(np.asarray, checks(
        {"alpha": np.full(n, 0.3), "eta": np.full(n, 1.5)}, wi, wo, rng.random((n, 3))))
    _, _, _, wo_s, weight = map(np.asarray, checks(
        {"alpha": alpha, "eta": np.full(n, 1.5)}, wi_s, wi_s, rng.random((n, 3))))
    k = len(wi_r)
    f_io, f_oi, f_exact, wi, wo = f_io[:k], f_oi[:k], f_exact[:k], wi[:k], wo[:k]
    assert f_io[-1] == pytest.approx(f_exact[-1], rel=1e-12) and f_io[-1] > 0  # normal incidence
    refl = wi[:, 2] * wo[:, 2] > 0
    np.testing.assert_allclose(f_io[refl], f_oi[refl], rtol=1e-9, atol=1e-300)
    eta_o = np.where(wo[:, 2] < 0, 1.5, 1.0)  # index on wo's side (outside 1, inside 1.5)
    eta_i = np.where(wi[:, 2] < 0, 1.5, 1.0)
    t = ~refl
    np.testing.assert_allclose(f_io[t] / eta_o[t] ** 2, f_oi[t] / eta_i[t] ** 2, rtol=1e-9,
                               atol=1e-300)
    assert np.count_nonzero(f_io[t]) > 50 and np.count_nonzero(f_io[refl]) > 50
    w = weight.reshape(2, len(thetas), n_u)
    up = (wo_s[:, 2] * wi_s[:, 2] > 0).reshape(2, len(thetas), n_u)
    cos_i = np.abs(np.cos(thetas))
    F = np.asarray(_schlick_d(cos_i, np.where(np.cos(thetas) > 0, 1.5, 1 / 1.5)))
    sigma = np.sqrt(F * (1 - F) / n_u)
    assert np.all(np.abs(up[0].mean(axis=1) - F) <= 4 * sigma + 1e-3), (up[0].mean(axis=1), F)
    np.testing.assert_allclose(w[0].mean(axis=1), 1.0, atol=2e-3)  # R + T = 1 (smooth limit)
    mean, err = w[1].mean(axis=1), w[1].std(axis=1) / np.sqrt(n_u)
    assert np.all(mean <= 1 + 4 * err + 1e-3), mean


#: (n, k) near 550 nm: copper from Elek 2010 appendix A (CONDUCTOR_PRESETS, green); gold and
#: aluminium from the usual tables (Johnson & Christy 1972; Rakić 1995), rounded.
METALS_550NM = {"copper": (1.04, 2.59), "gold": (0.43, 2.46), "aluminium": (0.96, 6.69)}


@pytest.mark.parametrize("metal", list(METALS_550NM))
def test_lazanyi_is_not_schlick_and_is_closer_to_exact_near_grazing(metal):
    """Lazányi–Szirmay-Kalos with its metal term (a from Hoffman's 82°) differs from Schlick and
    follows the exact reflectance more closely between 60° and 89° (measured max |ΔF| there:
    copper 0.041 → 0.0057, gold 0.0098 → 0.0062, aluminium 0.092 → 0.0076)."""
    from fitlab.fresnel import CONDUCTOR_FRESNEL_METHODS

    n, k = METALS_550NM[metal]
    c = np.cos(np.radians(np.linspace(60.0, 89.0, 291)))
    exact = _conductor_reference(c, n, k)
    sch = np.asarray(jax.jit(CONDUCTOR_FRESNEL_METHODS["schlick"])(c, n, k))
    laz = np.asarray(jax.jit(CONDUCTOR_FRESNEL_METHODS["lazanyi"])(c, n, k))
    assert np.max(np.abs(laz - sch)) > 5e-3
    assert np.max(np.abs(laz - exact)) < 0.7 * np.max(np.abs(sch - exact))
    assert np.max(np.abs(laz - exact)) < 0.008
