"""Issue 34 item 7: the command line starts without JAX. `fitlab --help`, `fitlab COMMAND
--help`, `fitlab --version` and `fitlab models` build every parser and every model (their
choices and help come from the registries) and import no JAX, SciPy, matplotlib or Mitsuba;
fitlab's JAX settings (fitlab/_jax.py) still precede any JAX that fitlab code uses."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: What the parsers and the model listing must not import (each takes 0.1 to 1 s).
HEAVY = ("jax", "jaxlib", "scipy", "matplotlib", "mitsuba", "drjit", "emcee")


def _python(code: str, **env) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}  # as a user has it
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=300, env={**environ, **env})


def test_parsers_help_version_and_models_import_no_jax():
    code = f"""
import contextlib, io, sys
import fitlab
assert "jax" not in sys.modules and "fitlab.fitting" not in sys.modules, "import fitlab is lazy"
import fitlab.cli
from fitlab.cli import COMMANDS, build_parser, main

build_parser()
loaded = [m for m in {HEAVY!r} if m in sys.modules]
assert not loaded, f"build_parser imported {{loaded}}"
out = io.StringIO()
with contextlib.redirect_stdout(out):
    for argv in [["--help"], ["--version"]] + [[c, "--help"] for c in COMMANDS]:
        try:
            main(argv)
        except SystemExit as exc:
            assert exc.code == 0, (argv, exc.code)
    assert main(["models"]) == 0
    assert main(["models", "--json"]) == 0
    assert main(["models", "spongecake(fiber,multiple=learned)"]) == 0
text = out.getvalue()
assert "--param alpha1=VALUE" in text and "bounds [" in text and "fitlab 0." in text
loaded = [m for m in {HEAVY!r} if m in sys.modules]
assert not loaded, f"--help, --version or models imported {{loaded}}"
"""
    proc = _python(code)
    assert proc.returncode == 0, proc.stderr


def test_fitlab_sets_jax_up_before_its_first_use():
    """float64 for JAX imported after fitlab.models (no JAX yet: the environment carries it),
    and both settings once a public name is used."""
    code = """
import sys
import fitlab.models
assert "jax" not in sys.modules
import jax
assert jax.config.values["jax_enable_x64"] is True
import fitlab
fitlab.fit  # a public name: JAX with fitlab's settings
assert jax.config.values["jax_cpu_enable_async_dispatch"] is False
assert jax.numpy.asarray(1.0).dtype == jax.numpy.float64
f = fitlab.eval_bsdf("lambertian", {"albedo": 0.5}, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0])
assert f.dtype == jax.numpy.float64 and abs(float(f) - 0.5 / 3.141592653589793) < 1e-15
"""
    proc = _python(code)
    assert proc.returncode == 0, proc.stderr


def test_package_root_is_lazy_and_complete():
    """Every name of fitlab.__all__ resolves (on first use) and dir() lists them; a subpackage
    named like a public function (fitlab.tradeoffs) leaves the function in place."""
    import fitlab
    import fitlab.tradeoffs.knobs  # noqa: F401

    assert set(fitlab.__all__) <= set(dir(fitlab))
    for name in fitlab.__all__:
        assert getattr(fitlab, name) is not None, name
    assert callable(fitlab.tradeoffs) and fitlab.models.MODELS is fitlab.MODELS


def test_a_fitlab_process_collects_young_objects_less_often():
    """``fitlab``'s main sets the cyclic collector's thresholds (fitlab.cli.GC_THRESHOLDS: a
    cold fit 15% less CPU), whatever they were."""
    r = _python("import gc, fitlab.cli\ngc.set_threshold(700, 10, 10)\n"
                "try:\n    fitlab.cli.main(['--version'])\nexcept SystemExit:\n    pass\n"
                "print(gc.get_threshold() == fitlab.cli.GC_THRESHOLDS, fitlab.cli.GC_THRESHOLDS[0] > 700)")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[-2:] == ["True", "True"], r.stdout
