"""fitlab.simulate.engine: Dr.Jit + Mitsuba 3 on a device, and the libLLVM its CPU backend loads.

Dr.Jit reads DRJIT_LIBLLVM_PATH once per process, when ``drjit`` is first imported, so each case
runs in a fresh Python (4 of them, ~3 s each); the pure helpers are tested here.
"""

from __future__ import annotations

import importlib.metadata
import json
import math
import os
import subprocess
import sys

import pytest

from fitlab.simulate import engine

#: A child's last stdout line is this JSON: the engine's fields and a Mitsuba BSDF value from the
#: LLVM backend (LLVM 15 and 16 abort the process on this kernel), or the FitlabError's text.
CHILD = """
import json, os
from fitlab.errors import FitlabError
from fitlab.simulate import engine
if os.environ.get("HIDE_PIP"):
    engine.pip_libllvm = lambda: None
out = {}
try:
    e = engine.load("cpu")
except FitlabError as exc:
    print(json.dumps({"error": str(exc)}))
    raise SystemExit(0)
mi, dr = e.mi, e.dr
si = dr.zeros(mi.SurfaceInteraction3f)
si.wi = mi.Vector3f(0, 0, 1)
bsdf = mi.load_dict({"type": "roughconductor", "alpha": 0.2})
value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(0.3, 0, 0.954))
out = dict(e._asdict(), dr=None, mi=None, again=engine.load("cpu") is e,
           set_variant=mi.variant(), value=float(value.x[0]))
try:
    out["gpu"] = engine.load("gpu").backend
except FitlabError as exc:
    out["gpu_error"] = str(exc)
print(json.dumps(out))
"""


def run_child(**env) -> dict:
    """Run CHILD in a fresh Python with ``env`` on top of this environment less the variables
    that choose a libLLVM; its JSON line."""
    base = {k: v for k, v in os.environ.items() if k not in (engine.ENV_PATH, engine.ENV_MODE)}
    proc = subprocess.run([sys.executable, "-c", CHILD], env={**base, **env}, text=True,
                          capture_output=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def default_child():
    return run_child()


def test_cpu_engine_loads_a_real_libllvm(default_child):
    out = default_child
    assert "error" not in out, out
    assert (out["variant"], out["backend"], out["set_variant"]) == ("llvm_ad_rgb", "llvm",
                                                                      "llvm_ad_rgb")
    assert os.path.isfile(out["libllvm"]) and "libLLVM" in os.path.basename(out["libllvm"])
    assert out["libllvm_source"] in ("system", "pip")
    major = engine.llvm_major(out["libllvm"])
    assert major is None or major >= engine.MIN_LLVM
    assert out["again"]
    # Mitsuba's rough conductor through the loaded LLVM: finite and positive (GGX, alpha 0.2)
    assert math.isfinite(out["value"]) and out["value"] > 0


def test_gpu_without_cuda_says_what_to_do(default_child):
    if "gpu" in default_child:
        pytest.skip("this machine has a CUDA GPU that Dr.Jit can use")
    message = default_child["gpu_error"]
    assert "\n" not in message and "--device cpu" in message and "NVIDIA" in message


def test_fitlab_llvm_pip_loads_the_pip_library():
    pip = engine.pip_libllvm()
    assert pip is not None, "karellen-llvm-core is a core dependency on Linux x86-64"
    files = {os.path.realpath(importlib.metadata.distribution(engine.PIP_PACKAGE).locate_file(f))
             for f in importlib.metadata.distribution(engine.PIP_PACKAGE).files}
    assert os.path.realpath(pip) in files
    out = run_child(FITLAB_LLVM="pip")
    assert "error" not in out, out
    assert out["libllvm_source"] == "pip"
    assert os.path.samefile(out["libllvm"], pip)
    assert math.isfinite(out["value"]) and out["value"] > 0


def test_missing_drjit_libllvm_path_is_named():
    out = run_child(DRJIT_LIBLLVM_PATH="/nonexistent/libLLVM.so")
    message = out["error"]
    assert "\n" not in message and "/nonexistent/libLLVM.so" in message


def test_no_pip_library_says_what_to_install():
    out = run_child(FITLAB_LLVM="pip", HIDE_PIP="1")
    message = out["error"]
    assert "\n" not in message and "pip install karellen-llvm-core" in message


@pytest.mark.parametrize("name, major", [
    ("libLLVM-15.so.1", 15), ("libLLVM-14.0.6.so.1", 14), ("libLLVM-17.so", 17),
    ("libLLVM.so.19.1", 19), ("libLLVM.so.23.1", 23), ("libLLVM.so", None),
    ("libLLVMSPIRVLib.so.15", None)])
def test_llvm_major_from_file_names(name, major):
    assert engine.llvm_major(f"/nowhere/{name}") == major


def test_newest_library_first():
    names = ["libLLVM-14.0.6.so.1", "libLLVM.so.19.1", "libLLVM-15.so.1", "libLLVM-9.so.1"]
    ordered = sorted(names, key=engine._version_key, reverse=True)
    assert ordered == ["libLLVM.so.19.1", "libLLVM-15.so.1", "libLLVM-14.0.6.so.1",
                       "libLLVM-9.so.1"]


def test_unknown_device_and_mode_are_errors(monkeypatch):
    from fitlab.errors import FitlabError

    with pytest.raises(FitlabError, match="device must be one of"):
        engine.load("tpu")
    monkeypatch.setenv(engine.ENV_MODE, "conda")
    with pytest.raises(FitlabError, match="FITLAB_LLVM must be"):
        engine._select_libllvm()
