// fitlab lookup table reader: kind fresnel (lut_fresnel_copper.exr)
// conductor Fresnel reflectance F(cos θ), method 'exact' (exact: unpolarized average of Rs and Rp for complex index n + ik)
// 32 x 1 texels; channels R, G, B
//   texture 0: r = R, g = G, b = B
//   axis 0: cos_theta in [0.0, 1.0], 32 samples, linear: x = lo + (hi - lo) t
// Sample i of an N-sample axis is at t = i/(N-1); texture coordinate s = (t(N-1)+0.5)/N.
// Spec: data_formats/lut_exr.md. Define FITLAB_LUT_TEXELFETCH for full-precision weights.

float fitlab_fresnel_t0(float x) { return clamp((x - 0.0) * 1.0, 0.0, 1.0); }

vec4 fitlab_fresnel_fetch(sampler2D tex, float t0, float t1, float row0) {
    float px = t0 * 31.0;
    float py = t1 * 0.0 + row0;
#ifdef FITLAB_LUT_TEXELFETCH
    float ix = min(floor(px), 30.0);
    float iy = min(floor(py), row0 + 0.0);
    float fx = px - ix, fy = py - iy;
    vec4 a = mix(texelFetch(tex, ivec2(int(ix) + 0, int(iy) + 0), 0), texelFetch(tex, ivec2(int(ix) + 1, int(iy) + 0), 0), fx);
    vec4 b = mix(texelFetch(tex, ivec2(int(ix) + 0, int(iy) + 0), 0), texelFetch(tex, ivec2(int(ix) + 1, int(iy) + 0), 0), fx);
    return mix(a, b, fy);
#else
    return textureLod(tex, vec2((px + 0.5) * 0.03125, (py + 0.5) * 1.0), 0.0);
#endif
}

// texture 0: (R, G, B)
vec4 fitlab_fresnel_tex0(sampler2D tex, float cos_theta) {
    return fitlab_fresnel_fetch(tex, fitlab_fresnel_t0(cos_theta), 0.0, 0.0);
}

vec4 fitlab_fresnel(sampler2D tex, float cos_theta) { return fitlab_fresnel_tex0(tex, cos_theta); }
