// fitlab lookup table reader: kind thin_layer (lut_thin_layer_chromium.exr)
// real-time form of the subsurface lobe of thin_layer(rough_conductor) (Guo et al. 2015 section 5.5) for η = 1.5: sin_theta_mean = sine of the lobe's mean direction's polar angle, positive toward the mirror azimuth (the mean lies in the plane of incidence); log10_kappa = log10 κ̂, the vMF concentration over outgoing directions with A3(κ̂) = |mean resultant| (eq. 18); E_<channel> = ∫ f cos θo dωo, the lobe's albedo (the remaining terms). Integrals of the subsurface component of f cos θo over the upper hemisphere
// 4 x 36 texels; channels sin_theta_mean, log10_kappa, E_R, E_G, E_B
//   texture 0: r = sin_theta_mean, g = log10_kappa, b = E_R, a = E_G
//   texture 1: r = E_B
//   axis 0: mu in [0.0, 1.0], 4 samples, linear: x = lo + (hi - lo) t
//   axis 1: kappa1 in [1.0, 1000000.0], 6 samples, log: x = lo (hi/lo)^t
//   axis 2: kappa2 in [1.0, 1000000.0], 6 samples, log: x = lo (hi/lo)^t
// Sample i of an N-sample axis is at t = i/(N-1); texture coordinate s = (t(N-1)+0.5)/N.
// Spec: data_formats/lut_exr.md. Define FITLAB_LUT_TEXELFETCH for full-precision weights.

float fitlab_thin_layer_t0(float x) { return clamp((x - 0.0) * 1.0, 0.0, 1.0); }
float fitlab_thin_layer_t1(float x) { return clamp(log(max(x, 1.0) * 1.0) * 0.07238241365054197, 0.0, 1.0); }
float fitlab_thin_layer_t2(float x) { return clamp(log(max(x, 1.0) * 1.0) * 0.07238241365054197, 0.0, 1.0); }

vec4 fitlab_thin_layer_fetch(sampler2D tex, float t0, float t1, float row0) {
    float px = t0 * 3.0;
    float py = t1 * 5.0 + row0;
#ifdef FITLAB_LUT_TEXELFETCH
    float ix = min(floor(px), 2.0);
    float iy = min(floor(py), row0 + 4.0);
    float fx = px - ix, fy = py - iy;
    vec4 a = mix(texelFetch(tex, ivec2(int(ix) + 0, int(iy) + 0), 0), texelFetch(tex, ivec2(int(ix) + 1, int(iy) + 0), 0), fx);
    vec4 b = mix(texelFetch(tex, ivec2(int(ix) + 0, int(iy) + 1), 0), texelFetch(tex, ivec2(int(ix) + 1, int(iy) + 1), 0), fx);
    return mix(a, b, fy);
#else
    return textureLod(tex, vec2((px + 0.5) * 0.25, (py + 0.5) * 0.027777777777777776), 0.0);
#endif
}

// texture 0: (sin_theta_mean, log10_kappa, E_R, E_G)
vec4 fitlab_thin_layer_tex0(sampler2D tex, float mu, float kappa1, float kappa2) {
    float t0 = fitlab_thin_layer_t0(mu), t1 = fitlab_thin_layer_t1(kappa1);
    float pz = fitlab_thin_layer_t2(kappa2) * 5.0;
    float k = min(floor(pz), 4.0);
    vec4 a = fitlab_thin_layer_fetch(tex, t0, t1, k * 6.0);
    vec4 b = fitlab_thin_layer_fetch(tex, t0, t1, (k + 1.0) * 6.0);
    return mix(a, b, pz - k);
}

// texture 1: (E_B)
vec4 fitlab_thin_layer_tex1(sampler2D tex, float mu, float kappa1, float kappa2) {
    float t0 = fitlab_thin_layer_t0(mu), t1 = fitlab_thin_layer_t1(kappa1);
    float pz = fitlab_thin_layer_t2(kappa2) * 5.0;
    float k = min(floor(pz), 4.0);
    vec4 a = fitlab_thin_layer_fetch(tex, t0, t1, k * 6.0);
    vec4 b = fitlab_thin_layer_fetch(tex, t0, t1, (k + 1.0) * 6.0);
    return mix(a, b, pz - k);
}

// The thin layer's subsurface lobe for incidence wi (unit, local frame, normal = +z) and
// boundary concentrations kappa1, kappa2 (clamped to the table's range by the lookup):
// its mean direction (unit; sin_theta_mean toward the mirror azimuth, in the plane of
// incidence), its vMF concentration kappa_hat and its albedo E of the first <= 3 channels
// (E_R, E_G, E_B). Read a pre-filtered environment map at
// `mean` with a vMF of kappa_hat and multiply by E (Guo et al. 2015 section 5.5).
void fitlab_thin_layer(sampler2D tex0, sampler2D tex1, vec3 wi, float kappa1, float kappa2,
        out vec3 mean, out float kappa_hat, out vec3 E) {
    float mu = clamp(wi.z, 0.0, 1.0);
    vec4 v0 = fitlab_thin_layer_tex0(tex0, mu, kappa1, kappa2);
    vec4 v1 = fitlab_thin_layer_tex1(tex1, mu, kappa1, kappa2);
    float s = clamp(v0.x, -1.0, 1.0);
    vec2 t = -wi.xy;
    float l = length(t);
    vec2 d = l > 0.0 ? t / l : vec2(0.0, 0.0);
    mean = vec3(s * d.x, s * d.y, sqrt(max(1.0 - s * s, 0.0)));
    kappa_hat = pow(10.0, v0.y);
    E = vec3(v0.z, v0.w, v1.x);
}
