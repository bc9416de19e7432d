"""GLSL (and HLSL) readers for fitlab lookup tables, with the exact index mapping of
``fitlab.lut`` (texel centres at the ends of every axis, the u⁸ / sqrt / log axis mappings,
linear interpolation between the slices of a third axis). data_formats/lut_exr.md documents the
layout; tests/lut/test_lut_glsl.py compiles the GLSL in Mesa's llvmpipe and compares it with direct
evaluation.

Texture set-up the code expects: the table's channels, in the order of the ``fitlab.channels``
attribute, packed four at a time into 2D textures (texture g holds channels 4g .. 4g+3, R G B A);
full width × height of the EXR, row 0 of the EXR at texture coordinate v = 0 (upload the rows in
file order); FLOAT or HALF internal format; GL_LINEAR filtering without mipmaps; CLAMP_TO_EDGE.
Hardware bilinear filtering keeps only about 8 fractional bits of the weights on many GPUs
(llvmpipe keeps full precision): ``#define FITLAB_LUT_TEXELFETCH`` before the snippet to
interpolate with four texelFetch taps and full-precision weights instead.
"""

from __future__ import annotations

import re

from fitlab.lut import MAPPINGS, Table, get_kind


def _f(x: float) -> str:
    """A float literal valid in GLSL and HLSL that round-trips float32."""
    s = repr(float(x))
    if s in ("inf", "-inf", "nan"):
        raise ValueError(f"cannot write {s} into shader code")
    return s if ("." in s or "e" in s) else s + ".0"


def _mapping_expr(axis, var: str) -> str:
    lo, hi = axis.lo, axis.hi
    inv = 1.0 / (hi - lo)
    if axis.mapping == "linear":
        t = f"({var} - {_f(lo)}) * {_f(inv)}"
    elif axis.mapping == "u8":
        t = f"sqrt(sqrt(sqrt(max(({_f(hi)} - {var}) * {_f(inv)}, 0.0))))"
    elif axis.mapping == "sqrt":
        t = f"sqrt(max(({var} - {_f(lo)}) * {_f(inv)}, 0.0))"
    elif axis.mapping == "log":
        import math

        t = f"log(max({var}, {_f(lo)}) * {_f(1.0 / lo)}) * {_f(1.0 / math.log(hi / lo))}"
    else:  # pragma: no cover - Axis validation forbids it
        raise ValueError(axis.mapping)
    return f"clamp({t}, 0.0, 1.0)"


def _arg_names(table: Table) -> tuple:
    """The reader's argument names: the kind's axis names (optional ones included) from the
    registry, never the file's strings (they become identifiers in the code)."""
    return get_kind(table.kind).all_axis_names[: len(table.axes)]


# GLSL's two-argument atan(y, x) is HLSL's atan2(y, x) (the generated code has no one-argument
# atan)
_HLSL = [(r"\bvec2\b", "float2"), (r"\bvec3\b", "float3"), (r"\bvec4\b", "float4"),
         (r"\bivec2\b", "int2"), (r"\bmix\b", "lerp"), (r"\bfract\b", "frac"),
         (r"\batan\(", "atan2(")]


def texture_groups(table: Table):
    """Channel names per texture: [[c0..c3], [c4..c7], ...]."""
    ch = list(table.channels)
    return [ch[i:i + 4] for i in range(0, len(ch), 4)]


def glsl(table: Table, *, prefix: str | None = None, source: str = "") -> str:
    """GLSL 3.30+ code: ``vec4 PREFIX_tex<g>(sampler2D tex, <axis coordinates>)`` per texture
    and a convenience function per kind (below)."""
    return _generate(table, prefix or f"fitlab_{table.kind}", source, "glsl")


def hlsl(table: Table, *, prefix: str | None = None, source: str = "") -> str:
    """The same functions in HLSL (Texture2D + SamplerState, SampleLevel at mip 0). Generated
    from the GLSL text by a fixed substitution; not compiled by fitlab's tests."""
    return _generate(table, prefix or f"fitlab_{table.kind}", source, "hlsl")


def _generate(table: Table, p: str, source: str, lang: str) -> str:
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", p):
        raise ValueError(f"shader prefix {p!r} must be an identifier")
    ax = table.axes
    args = _arg_names(table)
    W = ax[0].size
    N1 = ax[1].size if len(ax) > 1 else 1
    H = table.values.shape[0]
    groups = texture_groups(table)
    L = []
    L.append(f"// fitlab lookup table reader: kind {table.kind}{' (' + source + ')' if source else ''}")
    L.append(f"// {table.quantity}")
    L.append(f"// {W} x {H} texels; channels {', '.join(table.channels)}")
    for g, chans in enumerate(groups):
        slots = ", ".join(f"{'rgba'[i]} = {c}" for i, c in enumerate(chans))
        L.append(f"//   texture {g}: {slots}")
    for k, a in enumerate(ax):
        L.append(f"//   axis {k}: {a.name} in [{a.lo!r}, {a.hi!r}], {a.size} samples, "
                 f"{a.mapping}: {MAPPINGS[a.mapping].formula}")
    L.append("// Sample i of an N-sample axis is at t = i/(N-1); texture coordinate s = (t(N-1)+0.5)/N.")
    L.append("// Spec: data_formats/lut_exr.md. Define FITLAB_LUT_TEXELFETCH for full-precision weights.")
    if lang == "hlsl":
        tex_t, tex_arg, tex_pass = "Texture2D", "Texture2D tex, SamplerState smp", "tex, smp"
    else:
        tex_t, tex_arg, tex_pass = "sampler2D", "sampler2D tex", "tex"
    L.append("")
    for k, a in enumerate(ax):
        L.append(f"float {p}_t{k}(float x) {{ return {_mapping_expr(a, 'x')}; }}")
    L.append("")
    # 2D fetch at (t0, t1) within the slice starting at row `row0`
    L.append(f"vec4 {p}_fetch({tex_arg}, float t0, float t1, float row0) {{")
    L.append(f"    float px = t0 * {_f(W - 1)};")
    L.append(f"    float py = t1 * {_f(N1 - 1)} + row0;")
    L.append("#ifdef FITLAB_LUT_TEXELFETCH")
    L.append(f"    float ix = min(floor(px), {_f(max(W - 2, 0))});")
    L.append(f"    float iy = min(floor(py), row0 + {_f(max(N1 - 2, 0))});")
    L.append("    float fx = px - ix, fy = py - iy;")
    if lang == "hlsl":
        fetch = "tex.Load(int3(int(ix) + {dx}, int(iy) + {dy}, 0))"
    else:
        fetch = "texelFetch(tex, ivec2(int(ix) + {dx}, int(iy) + {dy}), 0)"
    dy1 = "1" if N1 > 1 else "0"
    L.append(f"    vec4 a = mix({fetch.format(dx=0, dy=0)}, {fetch.format(dx=1, dy=0)}, fx);")
    L.append(f"    vec4 b = mix({fetch.format(dx=0, dy=dy1)}, {fetch.format(dx=1, dy=dy1)}, fx);")
    L.append("    return mix(a, b, fy);")
    L.append("#else")
    uv = f"vec2((px + 0.5) * {_f(1.0 / W)}, (py + 0.5) * {_f(1.0 / H)})"
    if lang == "hlsl":
        L.append(f"    return tex.SampleLevel(smp, {uv}, 0.0);")
    else:
        L.append(f"    return textureLod(tex, {uv}, 0.0);")
    L.append("#endif")
    L.append("}")
    L.append("")
    coord_args = ", ".join(f"float {a}" for a in args)
    ts = ", ".join(f"{p}_t{k}({a})" for k, a in enumerate(args))
    for g, chans in enumerate(groups):
        L.append(f"// texture {g}: ({', '.join(chans)})")
        L.append(f"vec4 {p}_tex{g}({tex_arg}, {coord_args}) {{")
        if len(ax) == 1:
            L.append(f"    return {p}_fetch({tex_pass}, {p}_t0({args[0]}), 0.0, 0.0);")
        elif len(ax) == 2:
            L.append(f"    return {p}_fetch({tex_pass}, {ts}, 0.0);")
        else:
            N2 = ax[2].size
            L.append(f"    float t0 = {p}_t0({args[0]}), t1 = {p}_t1({args[1]});")
            L.append(f"    float pz = {p}_t2({args[2]}) * {_f(N2 - 1)};")
            L.append(f"    float k = min(floor(pz), {_f(N2 - 2)});")
            L.append(f"    vec4 a = {p}_fetch({tex_pass}, t0, t1, k * {_f(N1)});")
            L.append(f"    vec4 b = {p}_fetch({tex_pass}, t0, t1, (k + 1.0) * {_f(N1)});")
            L.append("    return mix(a, b, pz - k);")
        L.append("}")
        L.append("")
    L += _convenience(table, p, tex_arg, tex_pass, coord_args, args, lang)
    text = "\n".join(L) + "\n"
    if lang == "hlsl":
        for pat, rep in _HLSL:
            text = re.sub(pat, rep, text)
        text = text.replace("sampler2D", tex_t)
    return text


def _convenience(table, p, tex_arg, tex_pass, coord_args, args, lang="glsl"):
    call = ", ".join(args)
    k = table.kind
    if k == "thin_layer":
        return _thin_layer_convenience(table, p, lang)
    if k == "thin_layer_compensation":
        return _compensation_convenience(table, p, lang)
    if k == "D":
        a = table.axes[1]
        return [
            "// D(m) in 1/sr: the table stores pi alpha^2 D; alpha is clamped to the table's range.",
            f"float {p}({tex_arg}, float cos_theta_h, float alpha) {{",
            f"    float a = clamp(alpha, {_f(a.lo)}, {_f(a.hi)});",
            f"    return {p}_tex0({tex_pass}, cos_theta_h, a).r / (3.14159265358979 * a * a);",
            "}",
        ]
    if k == "model" and len(table.axes) == 3:
        phi = table.axes[2]
        fold = phi.hi <= 90.0  # fitlab.lut.kinds.phi_d_folds_by_reciprocity
        L = [
            "// (cos theta_h, cos theta_d, phi_d) of unit directions in the local frame (normal = +z),",
            "// phi_d in degrees: Rusinkiewicz's difference azimuth, the azimuth of wi about h from",
            "// t = R_z(phi_h) R_y(theta_h) x; scaled by sin theta_h: dx = s (wi.t), dy = s (wi.b).",
            "// |phi_d| (mirror symmetry of an isotropic BRDF)"
            + (", then min(phi_d, 180 - phi_d) (reciprocity)." if fold else "."),
            "// At h = n phi_d is undefined and an isotropic f does not depend on it: 90.",
            f"vec3 {p}_halfdiff(vec3 wi, vec3 wo) {{",
            "    vec3 h = normalize(wi + wo);",
            "    float dx = h.z * (wi.x * h.x + wi.y * h.y) - (h.x * h.x + h.y * h.y) * wi.z;",
            "    float dy = h.x * wi.y - h.y * wi.x;",
            "    float phi_d = (abs(dx) + abs(dy) > 0.0) ? degrees(atan(abs(dy), dx)) : 90.0;",
        ]
        if fold:
            L.append("    phi_d = min(phi_d, 180.0 - phi_d);")
        return L + [
            "    return vec3(clamp(h.z, 0.0, 1.0), clamp(dot(wi, h), 0.0, 1.0), phi_d);",
            "}",
            "// BRDF f(wi, wo) in 1/sr (no cosine) of the first <= 4 channels, 0 below the horizon.",
            f"vec4 {p}({tex_arg}, vec3 wi, vec3 wo) {{",
            "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec4(0.0, 0.0, 0.0, 0.0);  // HLSL: no scalar splat",
            f"    vec3 c = {p}_halfdiff(wi, wo);",
            f"    return {p}_tex0({tex_pass}, c.x, c.y, c.z);",
            "}",
        ]
    if k == "model":
        return [
            "// (cos theta_h, cos theta_d) of unit directions in the local frame (normal = +z).",
            f"vec2 {p}_halfdiff(vec3 wi, vec3 wo) {{",
            "    vec3 h = normalize(wi + wo);",
            "    return vec2(clamp(h.z, 0.0, 1.0), clamp(dot(wi, h), 0.0, 1.0));",
            "}",
            "// BRDF f(wi, wo) in 1/sr (no cosine) of the first <= 4 channels, 0 below the horizon.",
            f"vec4 {p}({tex_arg}, vec3 wi, vec3 wo) {{",
            "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec4(0.0, 0.0, 0.0, 0.0);  // HLSL: no scalar splat",
            f"    vec2 c = {p}_halfdiff(wi, wo);",
            f"    return {p}_tex0({tex_pass}, c.x, c.y);",
            "}",
        ]
    return [f"vec4 {p}({tex_arg}, {coord_args}) {{ return {p}_tex0({tex_pass}, {call}); }}"]


def _texture_arguments(table, lang):
    """(number of textures, their parameter declaration, the argument each reader passes)."""
    n_tex = len(texture_groups(table))
    if lang == "hlsl":
        decl = ", ".join(f"Texture2D tex{g}" for g in range(n_tex)) + ", SamplerState smp"
        return n_tex, decl, [f"tex{g}, smp" for g in range(n_tex)]
    return n_tex, ", ".join(f"sampler2D tex{g}" for g in range(n_tex)), \
        [f"tex{g}" for g in range(n_tex)]


def _thin_layer_convenience(table, p, lang):
    """The lobe for a pre-filtered environment lookup: mean direction, κ̂ and E (≤ 3 channels)."""
    n_tex, decl, pass_ = _texture_arguments(table, lang)
    n_E = min(3, len(table.channels) - 2)
    slots = [f"v{(2 + j) // 4}.{'xyzw'[(2 + j) % 4]}" for j in range(n_E)] + ["0.0"] * (3 - n_E)
    L = [
        "// The thin layer's subsurface lobe for incidence wi (unit, local frame, normal = +z) and",
        "// boundary concentrations kappa1, kappa2 (clamped to the table's range by the lookup):",
        "// its mean direction (unit; sin_theta_mean toward the mirror azimuth, in the plane of",
        "// incidence), its vMF concentration kappa_hat and its albedo E of the first <= 3 channels",
        f"// ({', '.join(table.channels[2:2 + n_E])}). Read a pre-filtered environment map at",
        "// `mean` with a vMF of kappa_hat and multiply by E (Guo et al. 2015 section 5.5).",
        f"void {p}({decl}, vec3 wi, float kappa1, float kappa2,",
        "        out vec3 mean, out float kappa_hat, out vec3 E) {",
        "    float mu = clamp(wi.z, 0.0, 1.0);",
    ]
    for g in range(n_tex):
        L.append(f"    vec4 v{g} = {p}_tex{g}({pass_[g]}, mu, kappa1, kappa2);")
    L += [
        "    float s = clamp(v0.x, -1.0, 1.0);",
        "    vec2 t = -wi.xy;",
        "    float l = length(t);",
        "    vec2 d = l > 0.0 ? t / l : vec2(0.0, 0.0);",
        "    mean = vec3(s * d.x, s * d.y, sqrt(max(1.0 - s * s, 0.0)));",
        "    kappa_hat = pow(10.0, v0.y);",
        f"    E = vec3({', '.join(slots)});",
        "}",
    ]
    return L


def _compensation_convenience(table, p, lang):
    """The thin layer's compensation lobe f_c(wi, wo) = D(mu_i) D(mu_o) / (pi Dbar), ≤ 3
    channels."""
    n_tex, decl, pass_ = _texture_arguments(table, lang)
    n = len(table.channels) // 3

    def slot(v, j):
        return f"{v}{j // 4}.{'xyzw'[j % 4]}"

    from fitlab.models.thin_layer_compensation import AZIMUTHAL_CONCENTRATION

    L = [
        "// fitlab's energy compensation of the thin layer (not in Guo et al. 2015): the lobe",
        "// f_c(wi, wo) = D(mu_i) D(mu_o) / (pi Dbar) * exp(b cos dphi) / I0(b) in 1/sr (no cosine;",
        "// reciprocal, albedo D(mu)), b = b0 sin(theta_i) sin(theta_o), dphi from the mirror azimuth,",
        f"// of the first <= 3 channels ({', '.join(table.channels[:min(3, n)])}): f = f_paper *",
        f"// {p}_scale(...) + {p}(...), with f_paper the thin layer without compensation.",
        "// wi, wo unit in the local frame (normal = +z); kappa clamped to the table's range.",
        f"vec3 {p}({decl}, vec3 wi, vec3 wo, float kappa1, float kappa2) {{",
        "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0, 0.0, 0.0);",
        f"    float conc = {_f(AZIMUTHAL_CONCENTRATION)};  // b0",
        "    float bs = conc * sqrt(max((1.0 - wi.z * wi.z) * (1.0 - wo.z * wo.z), 0.0));",
        "    float q = 0.25 * bs * bs, term = 1.0, i0 = 1.0;  // I0(b) by its series (b <= b0)",
        "    for (int j = 1; j < 12; ++j) { term *= q / float(j * j); i0 += term; }",
        "    float shape = exp(-conc * (wi.x * wo.x + wi.y * wo.y)) / i0;",
    ]
    for g in range(n_tex):
        L.append(f"    vec4 a{g} = {p}_tex{g}({pass_[g]}, wi.z, kappa1, kappa2);")
        L.append(f"    vec4 b{g} = {p}_tex{g}({pass_[g]}, wo.z, kappa1, kappa2);")
    terms = [f"{slot('a', j)} * {slot('b', j)} * shape / (3.14159265358979 * "
             f"max({slot('a', n + j)}, 1e-30))" for j in range(min(3, n))] \
        + ["0.0"] * (3 - min(3, n))
    L += [f"    return vec3({', '.join(terms)});", "}",
          "// g(mu_i) g(mu_o): the scale of the paper's f where it returns more light than the stack.",
          f"vec3 {p}_scale({decl}, vec3 wi, vec3 wo, float kappa1, float kappa2) {{",
          "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0, 0.0, 0.0);"]
    for g in range(n_tex):
        L.append(f"    vec4 a{g} = {p}_tex{g}({pass_[g]}, wi.z, kappa1, kappa2);")
        L.append(f"    vec4 b{g} = {p}_tex{g}({pass_[g]}, wo.z, kappa1, kappa2);")
    scales = [f"{slot('a', 2 * n + j)} * {slot('b', 2 * n + j)}" for j in range(min(3, n))] \
        + ["1.0"] * (3 - min(3, n))
    L += [f"    return vec3({', '.join(scales)});", "}"]
    return L


__all__ = ["glsl", "hlsl", "texture_groups"]
