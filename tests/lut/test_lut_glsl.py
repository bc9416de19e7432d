"""The generated GLSL, compiled and run in a real OpenGL implementation (Mesa llvmpipe through
EGL, headless, via moderngl): each table is written to EXR, read back, uploaded as textures and
sampled by a fragment shader that calls the generated reader at 4096 random points; the result
is compared with fitlab's direct evaluation (the model, or a fresh quadrature) and with the
float64 emulation of the same lookup (fitlab.lut.lookup).

Nothing is installed here: CI (.ci/run) and the README install Mesa's EGL (libegl1
libegl-mesa0 libgl1-mesa-dri libgbm1) and moderngl (test extra)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import skip_or_fail

from fitlab import lut
from fitlab.export import exr, shader

N_SIDE = 64  # 64 x 64 = 4096 random points per table
VINYL_WW = Path(__file__).resolve().parents[2] / "fits" / "brown_vinyl_weidlich_wilkie_lambert.json"


@pytest.fixture(scope="module")
def gl():
    from fitlab.export.materialx import ExportError, gl_context

    try:
        ctx = gl_context("pip install -e '.[test]' (moderngl) and Mesa's EGL (libegl1 "
                         "libegl-mesa0 libgl1-mesa-dri libgbm1)")
    except ExportError as exc:
        skip_or_fail(str(exc).removeprefix("--check cannot run: "))
    yield ctx
    ctx.release()


VERT = """#version 330
in vec2 pos;
void main() { gl_Position = vec4(pos, 0.0, 1.0); }
"""


def _frag(table, code, texelfetch):
    n_tex = len(shader.texture_groups(table))
    n_ax = len(table.axes)
    p = f"fitlab_{table.kind}"
    uniforms = "\n".join(f"uniform sampler2D lut{g};" for g in range(n_tex))
    coords = ", ".join(["c.x", "c.y", "c.z"][:n_ax])
    if table.kind == "D":
        body = f"out0 = vec4({p}(lut0, c.x, c.y) * 3.14159265358979 * clamp(c.y, " \
               f"{table.axes[1].lo!r}, {table.axes[1].hi!r}) * clamp(c.y, {table.axes[1].lo!r}, " \
               f"{table.axes[1].hi!r}), 0.0, 0.0, 0.0);"
        outs = "layout(location = 0) out vec4 out0;"
    else:
        outs = "\n".join(f"layout(location = {g}) out vec4 out{g};" for g in range(n_tex))
        body = "\n".join(f"out{g} = {p}_tex{g}(lut{g}, {coords});" for g in range(n_tex))
    return (f"#version 330\n{'#define FITLAB_LUT_TEXELFETCH' if texelfetch else ''}\n{uniforms}\n"
            f"uniform sampler2D coords;\n{outs}\n{code}\nvoid main() {{\n"
            f"    vec4 c = texelFetch(coords, ivec2(gl_FragCoord.xy), 0);\n    {body}\n}}\n")


def upload_table(ctx, prog, table):
    """The table's channels as the documented textures lut0, lut1, ... (four channels each,
    float32, bilinear, clamped), bound to ``prog``; returns them for release."""
    textures = []
    for g, chans in enumerate(shader.texture_groups(table)):
        idx = [table.channels.index(c) for c in chans]
        data = np.ascontiguousarray(table.values[:, :, idx].astype(np.float32))
        h, w, c = data.shape
        tex = ctx.texture((w, h), c, data.tobytes(), dtype="f4")
        tex.filter = (ctx.LINEAR, ctx.LINEAR)
        tex.repeat_x = tex.repeat_y = False
        tex.use(location=g)
        prog[f"lut{g}"] = g
        textures.append(tex)
    return textures


def run_on_gpu(ctx, table, points, texelfetch=False):
    """Evaluate the generated GLSL at ``points`` (P = N_SIDE², n_axes) → (P, C)."""
    code = shader.glsl(table)
    prog = ctx.program(vertex_shader=VERT, fragment_shader=_frag(table, code, texelfetch))
    groups = shader.texture_groups(table)
    textures = upload_table(ctx, prog, table)
    pts = np.zeros((N_SIDE * N_SIDE, 4), np.float32)
    pts[:, : points.shape[1]] = points
    ctex = ctx.texture((N_SIDE, N_SIDE), 4, pts.tobytes(), dtype="f4")
    ctex.filter = (ctx.NEAREST, ctx.NEAREST)
    ctex.use(location=7)
    prog["coords"] = 7
    n_out = 1 if table.kind == "D" else len(groups)
    targets = [ctx.texture((N_SIDE, N_SIDE), 4, dtype="f4") for _ in range(n_out)]
    fbo = ctx.framebuffer(color_attachments=targets)
    vbo = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], np.float32).tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "2f", "pos")])
    fbo.use()
    ctx.viewport = (0, 0, N_SIDE, N_SIDE)
    vao.render(mode=ctx.TRIANGLES)
    out = [np.frombuffer(fbo.read(components=4, dtype="f4", attachment=g), np.float32)
           .reshape(-1, 4) for g in range(n_out)]
    for obj in textures + targets + [ctex, fbo, vbo, vao, prog]:
        obj.release()
    res = np.concatenate(out, axis=1)[:, : len(table.channels)]
    return res.astype(np.float64)


def _points(table, seed=3):
    rng = np.random.default_rng(seed)
    t = rng.random((N_SIDE * N_SIDE, len(table.axes)))
    x = np.stack([a.to_x(t[:, k]) for k, a in enumerate(table.axes)], axis=-1)
    return x.astype(np.float32).astype(np.float64)  # what the shader receives


def _rel(a, b, scale):
    return np.abs(a - b) / np.maximum(np.abs(b), lut.REL_FLOOR * scale)


TABLES = {
    "D_ggx_u8": lambda: lut.make_spec("D", size=(256, 128), mappings=("u8", "linear")),
    "D_beckmann_linear": lambda: lut.make_spec("D", size=(256, 128), mappings=("linear", "log"),
                                               options={"distribution": "beckmann"}),
    "fresnel_copper": lambda: lut.make_spec("fresnel", params=lut.conductor_preset("copper")),
    "fresnel_glass": lambda: lut.make_spec("fresnel", params={"Y": {"eta": 1.5}}, size=(256,)),
    "albedo_conductor": lambda: lut.make_spec("albedo_conductor", size=(16, 16),
                                              orders={"n_u": 6, "n_phi": 3, "n_mu": 8}),
    "dfg": lambda: lut.make_spec("dfg", size=(16, 16), mappings=("linear", "sqrt"),
                                 orders={"n_u": 6, "n_phi": 3, "n_mu": 8}),
    "albedo_dielectric": lambda: lut.make_spec("albedo_dielectric", size=(8, 8, 4),
                                               orders={"n_u": 6, "n_phi": 3, "n_mu": 8}),
    "model_sum": lambda: lut.make_spec(
        "model", model="lambertian+rough_conductor", size=(128, 64),
        params={"R": {"albedo": 0.2, "alpha": 0.3, "n": 0.2, "k": 3.9},
                "G": {"albedo": 0.4, "alpha": 0.3, "n": 1.0, "k": 2.6}}),
    # the brown vinyl Weidlich–Wilkie fit with the φd axis (slices stacked along the height)
    "model_phi_d": lambda: lut.make_spec("model", size=(64, 32, 8), **_vinyl()),
    # the thin layer's real-time form: five channels in two textures, log κ axes
    "thin_layer": lambda: _thin_layer_spec(),
    # fitlab's compensation of the thin layer: six channels in two textures, log κ axes
    "thin_layer_compensation": lambda: lut.make_spec(
        "thin_layer_compensation", model="thin_layer(rough_conductor)", size=(6, 8, 8),
        params={c: {"eta": 1.5, "tau": t, "n2": n, "k2": k} for c, t, n, k in
                (("R", 0.1, 0.2, 3.9), ("G", 0.3, 1.0, 2.6), ("B", 0.0, 1.2, 2.4))}),
}


def _thin_layer_spec():
    return lut.make_spec("thin_layer", model="thin_layer(rough_conductor)", size=(6, 8, 8),
                         params={c: {"eta": 1.5, "tau": t, "n2": n, "k2": k} for c, t, n, k in
                                 (("R", 0.1, 0.2, 3.9), ("G", 0.3, 1.0, 2.6),
                                  ("B", 0.6, 1.2, 2.4))},
                         orders={"n_u": 12, "n_phi": 8})


def _vinyl():
    from fitlab.export.lut_files import from_fit

    model, options, params = from_fit(VINYL_WW)
    return dict(model=model, options=options, params=params)

#: Direct evaluation of the quadrature tables (a fresh quadrature per point, E_avg included)
#: at 4096 points would dominate the test time: they are compared at the first points only.
N_DIRECT = {"albedo_conductor": 64, "dfg": 128, "albedo_dielectric": 12, "thin_layer": 16}
_DIRECT, _BAKED = {}, {}


#: The dielectric albedo and thin-layer tables (three axes, a quadrature per texel) are the
#: costliest to bake and to evaluate directly: whole suite only; their GLSL path is the same 3D
#: one as model_phi_d's.
SLOW_TABLES = {"albedo_dielectric", "thin_layer"}


@pytest.mark.parametrize("texelfetch", [False, True], ids=["hw_bilinear", "texelfetch"])
@pytest.mark.parametrize("name", [pytest.param(n, marks=(pytest.mark.slow, pytest.mark.optimized))
                                  if n in SLOW_TABLES else n for n in TABLES])
def test_glsl_reproduces_direct_evaluation(gl, tmp_path, name, texelfetch, record_property):
    if name not in _BAKED:  # the same table for both filtering paths
        spec = TABLES[name]()
        dtype = "half" if name in ("D_ggx_u8", "fresnel_copper", "dfg") else "float"
        _BAKED[name] = spec, lut.bake(spec, dtype, check_points=0)
    spec, baked = _BAKED[name]
    path = tmp_path / f"{name}.exr"
    exr.write_exr(path, baked)
    table = exr.read_exr(path)  # what a renderer would load
    pts = _points(table)
    gpu = run_on_gpu(gl, table, pts, texelfetch)
    assert np.all(np.isfinite(gpu))
    emulated = lut.lookup(table, pts)
    scale = np.abs(table.values).reshape(-1, len(table.channels)).max(axis=0)
    # 1. The GLSL index mapping is the documented one: the GPU result equals the float64
    #    emulation up to float32 arithmetic (and 8-bit filter weights would show up here).
    shader_err = _rel(gpu, emulated, scale)
    assert shader_err.max() < 2e-4, f"{name}: GLSL vs emulated lookup {shader_err.max():.3g}"
    # 2. Against direct evaluation: the same error as the emulated lookup (the table's own
    #    interpolation error), reported per channel.
    n = N_DIRECT.get(table.kind, len(pts))
    if name not in _DIRECT:  # the same points for both filtering paths
        _DIRECT[name] = spec.evaluate(pts[:n])[0]
    direct = _DIRECT[name]
    e_gpu = _rel(gpu[:n], direct, scale)
    e_emu = _rel(emulated[:n], direct, scale)
    assert e_gpu.max() <= e_emu.max() * (1 + 1e-3) + 2e-4
    report = {ch: (float(e_gpu[:, k].max()), float(np.sqrt(np.mean(e_gpu[:, k] ** 2))))
              for k, ch in enumerate(table.channels)}
    record_property("relative_error_vs_direct", report)
    print(f"\n{name} [{'texelFetch' if texelfetch else 'hardware bilinear'}] vs direct "
          f"evaluation at {n} points: " + "; ".join(f"{ch}: max {m:.3g}, RMS {r:.3g}"
                                                     for ch, (m, r) in report.items()))


def test_glsl_reads_the_exact_sample_at_texel_centres(gl):
    """At the sample coordinates themselves the shader returns the stored values exactly."""
    # (not the u8 mapping: there the float32 coordinate 1 - t^8 itself is off by up to 4% of a
    # texel for t = 1/7, the quantization lut_exr.md describes)
    table = lut.bake(lut.make_spec("model", model="lambertian", size=(8, 4),
                                   mappings=("linear", "sqrt"), params={"Y": {"albedo": 0.5}}),
                     "float", check_points=0)
    table = table._replace(values=np.random.default_rng(0).random(table.values.shape))
    nodes = lut.grid_coords(table.axes)
    pts = np.zeros((N_SIDE * N_SIDE, 2))
    pts[: len(nodes)] = nodes
    pts[len(nodes):] = nodes[0]
    for tf in (False, True):
        gpu = run_on_gpu(gl, table, pts.astype(np.float32).astype(np.float64), tf)
        want = table.values.reshape(-1, 1)
        np.testing.assert_allclose(gpu[: len(nodes)], want, rtol=2e-5, atol=2e-6)


def test_hlsl_is_generated_from_the_same_mapping():
    table = lut.bake(lut.make_spec("fresnel", params={"Y": {"eta": 1.5}}, size=(16,)), "float",
                     check_points=0)
    g, h = shader.glsl(table), shader.hlsl(table)
    assert "float4 fitlab_fresnel_tex0(Texture2D tex, SamplerState smp, float cos_theta)" in h
    assert "SampleLevel" in h and "texelFetch" not in h and "lerp(" in h
    assert "vec4 fitlab_fresnel_tex0(sampler2D tex, float cos_theta)" in g
    # the same constants (texel-centre offsets and scales) in both
    nums = lambda s: sorted(set(__import__("re").findall(r"\d+\.\d+(?:e-?\d+)?", s)))  # noqa: E731
    assert nums(g) == nums(h)


# --------------------------------------------------------------------------------------------
# the model table's own reader: fitlab_model(tex, wi, wo) computes (cos θh, cos θd[, φd]) itself
# --------------------------------------------------------------------------------------------


def _frag_directions(code, texelfetch):
    return (f"#version 330\n{'#define FITLAB_LUT_TEXELFETCH' if texelfetch else ''}\n"
            "uniform sampler2D lut0;\nuniform sampler2D dir_i;\nuniform sampler2D dir_o;\n"
            f"layout(location = 0) out vec4 out0;\n{code}\nvoid main() {{\n"
            "    vec3 wi = texelFetch(dir_i, ivec2(gl_FragCoord.xy), 0).xyz;\n"
            "    vec3 wo = texelFetch(dir_o, ivec2(gl_FragCoord.xy), 0).xyz;\n"
            "    out0 = fitlab_model(lut0, wi, wo);\n}\n")


def run_directions_on_gpu(ctx, table, wi, wo, texelfetch=False):
    """fitlab_model(lut0, wi, wo) of the generated GLSL at N_SIDE² direction pairs → (P, C)."""
    prog = ctx.program(vertex_shader=VERT,
                       fragment_shader=_frag_directions(shader.glsl(table), texelfetch))
    objs = upload_table(ctx, prog, table)
    for loc, (name, d) in enumerate((("dir_i", wi), ("dir_o", wo)), start=1):
        px = np.zeros((N_SIDE * N_SIDE, 4), np.float32)
        px[:, :3] = d
        t = ctx.texture((N_SIDE, N_SIDE), 4, px.tobytes(), dtype="f4")
        t.filter = (ctx.NEAREST, ctx.NEAREST)
        t.use(location=loc)
        prog[name] = loc
        objs.append(t)
    target = ctx.texture((N_SIDE, N_SIDE), 4, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[target])
    vbo = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], np.float32).tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "2f", "pos")])
    fbo.use()
    ctx.viewport = (0, 0, N_SIDE, N_SIDE)
    vao.render(mode=ctx.TRIANGLES)
    out = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(-1, 4)
    for obj in objs + [target, fbo, vbo, vao, prog]:
        obj.release()
    return out[:, : len(table.channels)].astype(np.float64)


def _unreciprocal_conductor():
    import fitlab

    base = fitlab.get_model("rough_conductor")
    m = base._replace(name="rough_conductor_unreciprocal_glsl_test",
                      capabilities=base.capabilities._replace(reciprocal=False))
    fitlab.models.register_model(m, replace=True)
    return m.name


DIRECTION_TABLES = {
    "vinyl_2d": lambda: lut.make_spec("model", size=(64, 32), **_vinyl()),
    "vinyl_phi_d": lambda: lut.make_spec("model", size=(64, 32, 8), **_vinyl()),
    # no declared reciprocity: φd over [0°, 180°], folded by the mirror only
    "unreciprocal_phi_d_180": lambda: lut.make_spec(
        "model", model=_unreciprocal_conductor(), size=(64, 32, 9),
        params={"Y": {"alpha": 0.3, "n": 0.2, "k": 3.9}}),
}


@pytest.mark.parametrize("texelfetch", [False, True], ids=["hw_bilinear", "texelfetch"])
@pytest.mark.parametrize("name", list(DIRECTION_TABLES))
def test_glsl_model_reader_computes_and_folds_the_coordinates(gl, tmp_path, name, texelfetch):
    """fitlab_model(tex, wi, wo) at random direction pairs of the upper hemisphere (and a few
    below it) equals the float64 lookup at fitlab.lut.model_coordinates of the same float32
    directions: the shader's h, cos θh, cos θd and φd (atan, |φd|, the reciprocity fold)
    are the documented ones; against the model itself it has the table's parameterization
    error."""
    import fitlab

    spec = DIRECTION_TABLES[name]()
    baked = lut.bake(spec, "float", check_points=0)
    exr.write_exr(tmp_path / "m.exr", baked)
    table = exr.read_exr(tmp_path / "m.exr")
    rng = np.random.default_rng(7)
    n = N_SIDE * N_SIDE

    def hemi(u):
        r = np.sqrt(1 - u[:, 0] ** 2)
        return np.stack([r * np.cos(2 * np.pi * u[:, 1]), r * np.sin(2 * np.pi * u[:, 1]),
                         u[:, 0]], -1)

    wi, wo = hemi(rng.random((n, 2))), hemi(rng.random((n, 2)))
    wo[:16, 2] *= -1  # below the horizon: 0
    wi, wo = (w.astype(np.float32).astype(np.float64) for w in (wi, wo))
    gpu = run_directions_on_gpu(gl, table, wi, wo, texelfetch)
    assert np.all(np.isfinite(gpu)) and np.all(gpu[:16] == 0)
    emulated = lut.lookup(table, lut.model_coordinates(table.axes, wi, wo))
    scale = np.abs(table.values).reshape(-1, len(table.channels)).max(axis=0)
    err = _rel(gpu[16:], emulated[16:], scale)
    # the same bound as for the axis coordinates: the shader's float32 h, cos θd and φd
    # (measured: below 5e-6 on llvmpipe) do not add a lookup error of their own
    assert err.max() < 2e-4, f"{name}: GLSL vs emulated lookup at direction pairs: max {err.max():.3g}"
    model = table.model
    ref = np.stack([np.asarray(fitlab.eval_bsdf(model["name"], p, wi[16:], wo[16:],
                                                model["options"]))
                    for p in table.params.values()], -1)
    e_gpu = _rel(gpu[16:], ref, np.abs(ref).max(axis=0))
    e_emu = _rel(emulated[16:], ref, np.abs(ref).max(axis=0))
    print(f"\n{name} [{'texelFetch' if texelfetch else 'hardware bilinear'}] GLSL vs emulated "
          f"lookup: max {err.max():.3g}, 99th percentile {np.percentile(err, 99):.3g}; "
          f"fitlab_model vs the model at {n - 16} direction pairs: max {e_gpu.max():.3g}, RMS "
          f"{np.sqrt(np.mean(e_gpu ** 2)):.3g} (emulated lookup: RMS "
          f"{np.sqrt(np.mean(e_emu ** 2)):.3g})")
    assert np.sqrt(np.mean(e_gpu ** 2)) <= np.sqrt(np.mean(e_emu ** 2)) * 1.01 + 1e-4


# --------------------------------------------------------------------------------------------
# the thin layer's reader: fitlab_thin_layer(tex0, tex1, wi, kappa1, kappa2, mean, kappa, E)
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_glsl_thin_layer_reader_builds_the_lobe(gl, tmp_path):
    """The convenience reader turns the table's channels into the lobe a pre-filtered
    environment lookup needs: the unit mean direction in the plane of incidence on the mirror
    side (from sin_theta_mean), κ̂ = 10^log10_kappa and E per channel, equal to the same
    construction from the float64 lookup."""
    baked = lut.bake(_thin_layer_spec(), "half", check_points=0)
    exr.write_exr(tmp_path / "t.exr", baked)
    table = exr.read_exr(tmp_path / "t.exr")
    code = shader.glsl(table)
    frag = ("#version 330\nuniform sampler2D lut0;\nuniform sampler2D lut1;\n"
            "uniform sampler2D coords;\nuniform sampler2D dirs;\n"
            "layout(location = 0) out vec4 out0;\nlayout(location = 1) out vec4 out1;\n"
            f"{code}\nvoid main() {{\n"
            "    vec4 c = texelFetch(coords, ivec2(gl_FragCoord.xy), 0);\n"
            "    vec3 wi = texelFetch(dirs, ivec2(gl_FragCoord.xy), 0).xyz;\n"
            "    vec3 mean; float kappa; vec3 E;\n"
            "    fitlab_thin_layer(lut0, lut1, wi, c.y, c.z, mean, kappa, E);\n"
            "    out0 = vec4(mean, kappa); out1 = vec4(E, 0.0);\n}\n")
    prog = gl.program(vertex_shader=VERT, fragment_shader=frag)
    rng = np.random.default_rng(5)
    n = N_SIDE * N_SIDE
    pts = _points(table)
    mu = np.sqrt(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    s = np.sqrt(1 - mu * mu)
    wi = np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1).astype(np.float32).astype(float)
    objs = upload_table(gl, prog, table)
    for loc, (name, d) in enumerate((("coords", pts), ("dirs", wi)), start=4):
        px = np.zeros((n, 4), np.float32)
        px[:, :3] = d
        t = gl.texture((N_SIDE, N_SIDE), 4, px.tobytes(), dtype="f4")
        t.filter = (gl.NEAREST, gl.NEAREST)
        t.use(location=loc)
        prog[name] = loc
        objs.append(t)
    targets = [gl.texture((N_SIDE, N_SIDE), 4, dtype="f4") for _ in range(2)]
    fbo = gl.framebuffer(color_attachments=targets)
    vbo = gl.buffer(np.array([-1, -1, 3, -1, -1, 3], np.float32).tobytes())
    vao = gl.vertex_array(prog, [(vbo, "2f", "pos")])
    fbo.use()
    gl.viewport = (0, 0, N_SIDE, N_SIDE)
    vao.render(mode=gl.TRIANGLES)
    out = [np.frombuffer(fbo.read(components=4, dtype="f4", attachment=g), np.float32)
           .reshape(-1, 4).astype(float) for g in range(2)]
    for obj in objs + targets + [fbo, vbo, vao, prog]:
        obj.release()
    v = lut.lookup(table, np.stack([wi[:, 2], pts[:, 1], pts[:, 2]], -1))
    sn = np.clip(v[:, 0], -1, 1)
    d = -wi[:, :2] / np.linalg.norm(wi[:, :2], axis=1, keepdims=True)
    mean = np.column_stack([sn[:, None] * d, np.sqrt(1 - sn * sn)])
    np.testing.assert_allclose(np.linalg.norm(out[0][:, :3], axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(out[0][:, :3], mean, atol=2e-4)
    np.testing.assert_allclose(out[0][:, 3], 10 ** v[:, 1], rtol=1e-3)
    np.testing.assert_allclose(out[1][:, :3], v[:, 2:5], rtol=1e-3, atol=1e-6)
    # the mean lies on the mirror side of the plane of incidence: (mean.xy) · (wi.xy) <= 0
    # where the lobe leans that way (sin_theta_mean > 0)
    lean = sn > 1e-3
    assert np.all(np.sum(out[0][lean, :2] * wi[lean, :2], axis=1) <= 1e-6)
