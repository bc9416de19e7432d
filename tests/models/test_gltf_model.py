"""glTF 2.0's BRDF in the registry (``gltf_pbr``, ``gltf_pbr_clearcoat``): values against an
independent NumPy transcription of the specification's formulas (glTF 2.0 Specification,
Appendix B, "Complete Model" code block and "Specular BRDF"; KHR_materials_specular README,
"Implementation" and "Interaction with other extensions"; KHR_materials_clearcoat README,
"Implementation"), written here from the text with the spec's own variable names, and the
properties the model declares. The registry contract (tests/models/test_model_contract.py) covers
finiteness, sampling and χ² for both models."""

from __future__ import annotations

import numpy as np
import pytest

import fitlab
from fitlab.models.gltf_pbr import visibility_height_correlated


def _dir(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def spec_brdf(L, V, baseColor, metallic, roughness, ior=1.5, specular=1.0,
              specularColor=1.0, clearcoat=0.0, clearcoatRoughness=0.0):
    """Appendix B's "full code" with KHR_materials_specular/_ior's dielectric_f0/f90 and
    KHR_materials_clearcoat's coated_material; N = +z. One colour channel (specularColor grey)."""
    N = np.array([0.0, 0.0, 1.0])
    H = (L + V) / np.linalg.norm(L + V, axis=-1, keepdims=True)
    VdotH, NdotH = np.sum(V * H, -1), H @ N
    NdotL, NdotV = L @ N, V @ N

    def D(a):
        return a**2 * (NdotH > 0) / (np.pi * (NdotH**2 * (a**2 - 1) + 1) ** 2)

    def G(a):  # height-correlated Smith ("Specular BRDF")
        return 2 * abs(NdotL) * abs(NdotV) / (
            abs(NdotV) * np.sqrt(a**2 + (1 - a**2) * NdotL**2)
            + abs(NdotL) * np.sqrt(a**2 + (1 - a**2) * NdotV**2))

    def specular_brdf(a):
        return D(a) * G(a) / (4 * abs(NdotV) * abs(NdotL))

    fresnel_w = (1 - abs(VdotH)) ** 5
    diffuse_brdf = (1 / np.pi) * baseColor
    dielectric_f0 = min(((ior - 1) / (ior + 1)) ** 2 * specularColor, 1.0) * specular
    dielectric_f90 = specular
    dielectric_fresnel = dielectric_f0 + (dielectric_f90 - dielectric_f0) * fresnel_w
    sb = specular_brdf(roughness**2)
    dielectric_brdf = dielectric_fresnel * sb + (1 - dielectric_fresnel) * diffuse_brdf
    metal_fresnel = baseColor + (1 - baseColor) * fresnel_w
    metal_brdf = metal_fresnel * sb
    material = (1 - metallic) * dielectric_brdf + metallic * metal_brdf
    if clearcoat:
        clearcoat_fresnel = 0.04 + (1 - 0.04) * (1 - abs(NdotV)) ** 5
        clearcoat_brdf = specular_brdf(clearcoatRoughness**2)
        material = (1 - clearcoat * clearcoat_fresnel) * material \
            + clearcoat * clearcoat_fresnel * clearcoat_brdf
    return material


CASES = [
    dict(base_color=0.8, metallic=1.0, roughness_factor=0.3),
    dict(base_color=0.5, metallic=0.0, roughness_factor=0.5),
    dict(base_color=0.2, metallic=0.4, roughness_factor=0.15, ior=1.8, specular=0.7,
         specular_color=1.6),
    dict(base_color=0.9, metallic=0.0, roughness_factor=0.9, ior=1.2, specular=0.3,
         specular_color=0.5),
]
NAMES = {"base_color": "baseColor", "roughness_factor": "roughness",
         "specular_color": "specularColor", "clearcoat_roughness_factor": "clearcoatRoughness"}


def _pairs(n=400, seed=5):
    rng = np.random.default_rng(seed)
    wi = _dir(rng.uniform(0, 88, n), rng.uniform(0, 360, n))
    wo = _dir(rng.uniform(0, 88, n), rng.uniform(0, 360, n))
    return wi, wo


def _full(model, p):
    d = {q.name: q.default for q in fitlab.get_model(model).parameters}
    d.update(p)
    return d


@pytest.mark.parametrize("case", range(len(CASES)))
def test_core_equals_the_specification(case):
    wi, wo = _pairs()
    p = _full("gltf_pbr", CASES[case])
    ours = np.asarray(fitlab.eval_bsdf("gltf_pbr", p, wi, wo))
    ref = spec_brdf(wi, wo, **{NAMES.get(k, k): v for k, v in p.items()})
    np.testing.assert_allclose(ours, ref, rtol=1e-10, atol=0)


def test_clearcoat_equals_the_specification_and_is_not_reciprocal():
    wi, wo = _pairs()
    p = _full("gltf_pbr_clearcoat", {**CASES[1], "clearcoat": 0.8,
                                     "clearcoat_roughness_factor": 0.2})
    ours = np.asarray(fitlab.eval_bsdf("gltf_pbr_clearcoat", p, wi, wo))
    ref = spec_brdf(wi, wo, **{NAMES.get(k, k): v for k, v in p.items()})
    np.testing.assert_allclose(ours, ref, rtol=1e-10, atol=0)
    swapped = np.asarray(fitlab.eval_bsdf("gltf_pbr_clearcoat", p, wo, wi))
    assert np.max(np.abs(swapped - ours) / ours) > 1e-2  # the coat's Fresnel sees N·V only
    assert not fitlab.get_model("gltf_pbr_clearcoat").capabilities.reciprocal
    core = _full("gltf_pbr", CASES[1])
    np.testing.assert_allclose(fitlab.eval_bsdf("gltf_pbr", core, wo, wi),
                               fitlab.eval_bsdf("gltf_pbr", core, wi, wo), rtol=1e-12)


def test_metal_at_normal_incidence_is_D_V_F0():
    """metallic = 1, L = V = N: f = D(1) ν(1) F0 with D = 1/(π α²), ν = 1/4, F0 = baseColor."""
    r = 0.4
    p = _full("gltf_pbr", {"base_color": 0.7, "metallic": 1.0, "roughness_factor": r})
    n = np.array([[0.0, 0.0, 1.0]])
    f = float(fitlab.eval_bsdf("gltf_pbr", p, n, n)[0])
    assert f == pytest.approx(0.7 / (np.pi * (r * r) ** 2) / 4.0, rel=1e-12)


def test_alpha_is_roughness_squared_and_D_is_walters_ggx():
    """The specular lobe of a metal is Walter's GGX D with α = r² times the height-correlated ν
    and F; against fitlab's rough_conductor (separable G, exact Fresnel), the ratio at the
    mirror direction is ν_hc / ν_sep × F_schlick / F_exact, all computed here."""
    from fitlab.fresnel import fresnel_conductor_exact
    from fitlab.microfacet import G_GGX

    r, n, k = 0.5, 0.2, 3.9
    alpha = r * r
    wi = _dir(np.array([30.0]), np.array([0.0]))
    wo = _dir(np.array([30.0]), np.array([180.0]))
    F0 = float(fresnel_conductor_exact(np.array(1.0), n, k))
    g = float(fitlab.eval_bsdf("gltf_pbr", _full("gltf_pbr", {"base_color": F0, "metallic": 1.0,
                                                              "roughness_factor": r}), wi, wo)[0])
    c = float(fitlab.eval_bsdf("rough_conductor", {"alpha": alpha, "n": n, "k": k}, wi, wo)[0])
    cos = np.cos(np.radians(30.0))
    nu_hc = float(visibility_height_correlated(wi, wo, alpha)[0])
    nu_sep = float(G_GGX(wi, wo, alpha)[0]) / (4 * cos * cos)
    F_s = F0 + (1 - F0) * (1 - cos) ** 5
    F_e = float(fresnel_conductor_exact(np.array(cos), n, k))
    assert g / c == pytest.approx(nu_hc / nu_sep * F_s / F_e, rel=1e-10)


def test_height_correlated_visibility():
    """ν = 1/(4 cos θi cos θo (1 + Λ(i) + Λ(o))) (Heitz 2014 eq. 99), at least the separable
    G1 G1/(4 cos cos), equal at normal incidence."""
    from fitlab.microfacet import G_GGX, Lambda_GGX

    wi, wo = _pairs(200, seed=9)
    for alpha in (0.01, 0.2, 0.8):
        nu = np.asarray(visibility_height_correlated(wi, wo, alpha))
        heitz = 1.0 / (4 * wi[:, 2] * wo[:, 2] * (1 + np.asarray(Lambda_GGX(wi, alpha))
                                                     + np.asarray(Lambda_GGX(wo, alpha))))
        np.testing.assert_allclose(nu, heitz, rtol=1e-10)
        sep = np.asarray(G_GGX(wi, wo, alpha)) / (4 * wi[:, 2] * wo[:, 2])
        assert np.all(nu >= sep * (1 - 1e-12))
        n = np.array([[0.0, 0.0, 1.0]])
        assert float(visibility_height_correlated(n, n, alpha)[0]) == pytest.approx(0.25)


def test_specular_zero_is_lambert():
    wi, wo = _pairs(100)
    p = _full("gltf_pbr", {"base_color": 0.6, "metallic": 0.0, "specular": 0.0})
    np.testing.assert_allclose(fitlab.eval_bsdf("gltf_pbr", p, wi, wo), 0.6 / np.pi, rtol=1e-12)


def test_not_energy_conserving_at_grazing_as_declared():
    """A white dielectric base reflects more than all light at 85° (Appendix B's fresnel_mix),
    which is why the model declares energy_conserving=False; at 30° it stays below 1."""
    rng = np.random.default_rng(3)
    n = 200_000
    p = _full("gltf_pbr", {"base_color": 1.0, "metallic": 0.0, "roughness_factor": 0.5})
    albedo = {}
    for t in (30.0, 85.0):
        wi = np.broadcast_to(_dir(np.array(t), np.array(0.0)), (n, 3))
        _, w, _ = fitlab.sample_bsdf("gltf_pbr", p, wi, rng.random((n, 3)))
        w = np.asarray(w)
        albedo[t] = (w.mean(), w.std() / np.sqrt(n))
    assert albedo[30.0][0] < 1.0
    assert albedo[85.0][0] > 1.05 + 4 * albedo[85.0][1]
    assert not fitlab.get_model("gltf_pbr").capabilities.energy_conserving


def spec_anisotropic_specular(L, V, alpha, strength, rotation_rad):
    """KHR_materials_anisotropy "Anisotropy" and "Implementation": D_GGX_anisotropic ·
    V_GGX_anisotropic with
    at = mix(alphaRoughness, 1, anisotropy²), ab = alphaRoughness, T = the tangent +x turned by
    the rotation, B = N × T (written from the README's GLSL)."""
    T = np.array([np.cos(rotation_rad), np.sin(rotation_rad), 0.0])
    N = np.array([0.0, 0.0, 1.0])
    B = np.cross(N, T)
    H = (L + V) / np.linalg.norm(L + V, axis=-1, keepdims=True)
    at = alpha * (1 - strength**2) + strength**2
    ab = alpha
    NdotH, TdotH, BdotH = H @ N, H @ T, H @ B
    a2 = at * ab
    f = np.stack([ab * TdotH, at * BdotH, a2 * NdotH], -1)
    w2 = a2 / np.sum(f * f, -1)
    D = a2 * w2 * w2 / np.pi
    NdotL, NdotV = L @ N, V @ N
    GGXV = NdotL * np.linalg.norm(np.stack([at * (V @ T), ab * (V @ B), NdotV], -1), axis=-1)
    GGXL = NdotV * np.linalg.norm(np.stack([at * (L @ T), ab * (L @ B), NdotL], -1), axis=-1)
    # The README's (non-normative) GLSL clamps this to [0, 1]; the normative text derives ν from
    # D as Appendix B does, unclamped (ν = G/(4 N·L N·V) exceeds 1 near grazing directions),
    # and so does fitlab (at strength 0 it is then Appendix B's ν exactly).
    Vis = 0.5 / (GGXV + GGXL)
    return D * Vis


def test_anisotropic_metal_equals_the_extension():
    """A metal (metallic 1): f = F_metal · D · V with the extension's anisotropic D and V."""
    wi, wo = _pairs(300, seed=13)
    p = _full("gltf_pbr_anisotropic", {"base_color": 0.8, "metallic": 1.0,
                                       "roughness_factor": 0.35, "anisotropy_strength": 0.7,
                                       "anisotropy_rotation": 30.0})
    ours = np.asarray(fitlab.eval_bsdf("gltf_pbr_anisotropic", p, wi, wo))
    H = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    F = 0.8 + 0.2 * (1 - np.abs(np.sum(wo * H, -1))) ** 5
    ref = F * spec_anisotropic_specular(wi, wo, 0.35**2, 0.7, np.radians(30.0))
    np.testing.assert_allclose(ours, ref, rtol=1e-10)
    # strength 0 is the isotropic model
    iso = {**p, "anisotropy_strength": 0.0}
    core = {k: v for k, v in iso.items() if not k.startswith("anisotropy")}
    np.testing.assert_allclose(fitlab.eval_bsdf("gltf_pbr_anisotropic", iso, wi, wo),
                               fitlab.eval_bsdf("gltf_pbr", core, wi, wo), rtol=1e-12)


def test_transmission_equals_the_extension():
    """KHR_materials_transmission (thin-walled): reflection keeps (1 - t) of the diffuse base;
    the transmitted side is (1 - F) t baseColor ν_T D_T with H_T = normalize(V - 2(N·L)N + L),
    N on the viewer's side, and the separable ν_T of its "Implementation Notes"."""
    rng = np.random.default_rng(17)
    n = 300
    wi = _dir(rng.uniform(0, 85, n), rng.uniform(0, 360, n))
    wo_r = _dir(rng.uniform(0, 85, n), rng.uniform(0, 360, n))
    wo_t = wo_r * np.array([1.0, 1.0, -1.0])
    p = _full("gltf_pbr_transmission", {"base_color": 0.7, "metallic": 0.0,
                                        "roughness_factor": 0.4, "transmission": 0.6})
    core = {k: v for k, v in p.items() if k != "transmission"}
    # reflection side: the core with the diffuse base scaled by 1 - t
    refl = np.asarray(fitlab.eval_bsdf("gltf_pbr_transmission", p, wi, wo_r))
    h = (wi + wo_r) / np.linalg.norm(wi + wo_r, axis=-1, keepdims=True)
    F_r = 0.04 + 0.96 * (1 - np.abs(np.sum(wo_r * h, -1))) ** 5
    ref_r = spec_brdf(wi, wo_r, **{NAMES.get(k, k): v for k, v in core.items()}) \
        - (1 - p["metallic"]) * 0.6 * (1 - F_r) * 0.7 / np.pi
    np.testing.assert_allclose(refl, ref_r, rtol=1e-10)
    # transmitted side
    N = np.array([0.0, 0.0, -1.0])  # the viewer's side
    L, V = wi, wo_t
    H = V - 2 * (L @ N)[:, None] * N + L
    H = H / np.linalg.norm(H, axis=-1, keepdims=True)
    a = 0.4**2
    NdotH, NdotL, NdotV = H @ N, L @ N, V @ N
    D = a**2 * (NdotH > 0) / (np.pi * (NdotH**2 * (a**2 - 1) + 1) ** 2)
    nu = (1 / (abs(NdotL) + np.sqrt(a**2 + (1 - a**2) * NdotL**2))) \
        * (1 / (abs(NdotV) + np.sqrt(a**2 + (1 - a**2) * NdotV**2)))
    F = 0.04 + 0.96 * (1 - np.abs(np.sum(V * H, -1))) ** 5
    ref_t = (1 - F) * 0.6 * 0.7 * nu * D
    ours_t = np.asarray(fitlab.eval_bsdf("gltf_pbr_transmission", p, wi, wo_t))
    np.testing.assert_allclose(ours_t, ref_t, rtol=1e-10)
    assert fitlab.get_model("gltf_pbr_transmission").capabilities.transmission
