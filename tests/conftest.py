"""Shared test set-up: float64 on, strict dtype promotion, skips that CI turns into failures,
one compilation cache per test session and compiled code released after each test module."""

from __future__ import annotations

import ctypes
import functools
import gc
import json
import os
import shutil
import sys
import tempfile

from fitlab.cli import tune_collector

#: Python's cyclic collector in a test process as in a ``fitlab`` process (fitlab.cli.GC_THRESHOLDS):
#: tracing and lowering allocate millions of short-lived objects, and with the default
#: thresholds full collections walked the whole heap (JAX, matplotlib, the registry) again and
#: again: about 10% of a test process's CPU time. The heap a module leaves behind is frozen
#: after its release (:func:`_release_compiled_code`).
tune_collector()

#: XLA settings the tests compile with, set before JAX starts (and inherited by the `fitlab`
#: processes tests start): the legacy CPU emitters (XLA_FLAGS) and JAX's
#: ``jax_disable_most_optimizations`` (XLA's backend at -O0 without its expensive LLVM passes)
#: compile the suite's thousands of small kernels in about 40% less time (most of the suite's
#: time is XLA compiling; its kernels run on tens to thousands of rows, where optimized code
#: saves little). Neither setting relaxes IEEE semantics (no fast math either way). A test whose
#: time goes into running compiled code (an MCMC chain, a network's training: 5 to 15 times
#: slower at -O0) is marked ``optimized``: it compiles at XLA's default optimization level
#: (the fixture ``_optimization_of_marked_tests``). What users get, XLA's defaults, is tested
#: too: tests/project/test_compiler_settings.py runs the registry contract and the sampling tests under
#: them. FITLAB_TEST_XLA_DEFAULTS=1 runs a session under XLA's defaults; a setting already in
#: XLA_FLAGS is left as it is.
#: ``xla_cpu_multi_thread_eigen=false``: each test process runs XLA's operations on one thread
#: (the suite's two processes already fill the two cores; Eigen's pool made them contend):
#: quick tier 306 s against 320-324 s, 530 against 550-566 user-seconds.
TEST_XLA_FLAGS = {"xla_cpu_use_fusion_emitters": "false", "xla_cpu_multi_thread_eigen": "false"}
#: JAX reads it when it starts (this process and the `fitlab` processes tests start); the
#: ``optimized`` marker changes it per test through jax.config.
NO_OPTIMIZATION_ENV = "JAX_DISABLE_MOST_OPTIMIZATIONS"
XLA_DEFAULTS_ENV = "FITLAB_TEST_XLA_DEFAULTS"
FAST_COMPILE = os.environ.get(XLA_DEFAULTS_ENV, "").strip() in ("", "0")
if FAST_COMPILE:
    _flags = os.environ.get("XLA_FLAGS", "").split()
    _flags += [f"--{k}={v}" for k, v in TEST_XLA_FLAGS.items()
               if not any(f.startswith(f"--{k}=") for f in _flags)]
    os.environ["XLA_FLAGS"] = " ".join(_flags)
    os.environ.setdefault(NO_OPTIMIZATION_ENV, "1")

# Dr.Jit picks its libLLVM once, at `import drjit`: choose a usable one (LLVM >= 17, the
# system's or the pip package's; fitlab/simulate/engine.py) before any test imports mitsuba.
from fitlab.simulate.engine import select_libllvm  # noqa: E402

select_libllvm()


def xla_default_flags(flags: str) -> str:
    """XLA_FLAGS without the settings above (a user's own settings stay)."""
    return " ".join(f for f in flags.split()
                    if not any(f.startswith(f"--{k}=") for k in TEST_XLA_FLAGS))


def user_environment() -> dict:
    """This process's environment as a user's shell has it: XLA's default settings. A test that
    compares a command's output with committed bytes (made by that command under the defaults)
    runs it in a child process with this environment: compiled at other settings, a value's
    last digit can differ."""
    env = dict(os.environ, XLA_FLAGS=xla_default_flags(os.environ.get("XLA_FLAGS", "")))
    env.pop(NO_OPTIMIZATION_ENV, None)
    return env


def _same_values(got, want, rtol, where):
    """Two parsed JSON values or CSV cells: equal, numbers within rtol (recursive)."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and sorted(got) == sorted(want), where
        for k in want:
            _same_values(got[k], want[k], rtol, f"{where}.{k}")
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want)):
            _same_values(g, w, rtol, f"{where}[{i}]")
    elif isinstance(want, (int, float)) and not isinstance(want, bool):
        assert isinstance(got, (int, float)) and not isinstance(got, bool), (where, got, want)
        assert got == want or (got != got and want != want) or \
            abs(got - want) <= rtol * max(abs(got), abs(want)), (where, got, want)  # NaN = NaN
    else:
        assert got == want, (where, got, want)


def _csv_cell(text):
    try:
        return float(text)
    except ValueError:
        return text


def assert_same_csv(got_text: str, want_text: str, rtol: float = 1e-9, where: str = "csv"):
    """Same header, same text cells, numbers within rtol: what a committed example promises on
    another machine (its bytes are promised for one machine and one set of run conditions: the
    last binary digits of a float can follow memory alignment in BLAS or the CPU's vector
    width in XLA)."""
    import csv
    import io

    got = [[_csv_cell(c) for c in row] for row in csv.reader(io.StringIO(got_text))]
    want = [[_csv_cell(c) for c in row] for row in csv.reader(io.StringIO(want_text))]
    _same_values(got, want, rtol, where)


def assert_same_json(got, want, rtol: float = 1e-9, where: str = "json"):
    """Parsed JSON records equal, numbers within rtol (see assert_same_csv)."""
    _same_values(got, want, rtol, where)


import jax  # noqa: E402  (after XLA_FLAGS)
import pytest  # noqa: E402

# Tests never write to the user's compilation cache (fitlab fit keeps one by default): the
# session gets a fresh temporary one instead, shared by the pytest-xdist workers and by the
# `fitlab` processes the tests start (they inherit the environment), deleted at the end. A kernel
# that several test modules compile is then compiled once and loaded after (the per-module
# release below would otherwise make each module compile it again). FITLAB_NO_CACHE=1 in the
# environment turns it off, as for fitlab itself.
SESSION_CACHE_ENV = "FITLAB_TEST_SESSION_CACHE"
_OWN_SESSION_CACHE = None
if os.environ.get("FITLAB_NO_CACHE", "").strip() in ("", "0"):
    if not os.environ.get(SESSION_CACHE_ENV):  # the controller (or a plain run) makes it
        _OWN_SESSION_CACHE = tempfile.mkdtemp(prefix="fitlab-test-xla-")
        os.environ[SESSION_CACHE_ENV] = _OWN_SESSION_CACHE
    os.environ["FITLAB_CACHE_DIR"] = os.environ[SESSION_CACHE_ENV]
    from fitlab.fitting.cache import enable_compilation_cache

    enable_compilation_cache()

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


# The suite's compilations, counted per test process and summed in the summary line
# "XLA: ... compilations" (pytest-xdist hands each worker's counts to the controller): most of
# the suite's time is XLA compiling, so this is the figure that changes with it.
_COMPILES = {"backend_compiles": 0, "backend_seconds": 0.0, "traces": 0, "trace_seconds": 0.0,
             "lowering_seconds": 0.0, "cache_hits": 0}


def _count_duration(event, seconds, **_):
    if event == "/jax/core/compile/backend_compile_duration":
        _COMPILES["backend_compiles"] += 1
        _COMPILES["backend_seconds"] += seconds
    elif event == "/jax/core/compile/jaxpr_trace_duration":
        _COMPILES["traces"] += 1
        _COMPILES["trace_seconds"] += seconds
    elif event == "/jax/core/compile/jaxpr_to_mlir_module_duration":
        _COMPILES["lowering_seconds"] += seconds


def _count_event(event, **_):
    if event == "/jax/compilation_cache/cache_hits":
        _COMPILES["cache_hits"] += 1


jax.monitoring.register_event_duration_secs_listener(_count_duration)
jax.monitoring.register_event_listener(_count_event)
_WORKER_COMPILES = []


def pytest_sessionfinish(session):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # a pytest-xdist worker: report to the controller
        workeroutput["fitlab_compiles"] = dict(_COMPILES)
    elif os.environ.get(RECORD_ENV) and _RECORDED:
        with open(MODULE_SECONDS, "w", encoding="utf-8") as fh:
            json.dump({k: round(v, 1) for k, v in sorted(_RECORDED.items())}, fh, indent=1)
            fh.write("\n")


def pytest_testnodedown(node, error):
    counts = getattr(node, "workeroutput", {}).get("fitlab_compiles")
    if counts:
        _WORKER_COMPILES.append(counts)


def pytest_terminal_summary(terminalreporter):
    parts = _WORKER_COMPILES or [_COMPILES]
    total = {k: sum(p[k] for p in parts) for k in _COMPILES}
    terminalreporter.write_line(
        f"XLA: {total['backend_compiles']} compilations ({total['backend_seconds']:.0f} s), "
        f"{total['cache_hits']} loaded from the session cache, {total['traces']} traces "
        f"({total['trace_seconds']:.0f} s), lowering {total['lowering_seconds']:.0f} s, "
        f"in {len(parts)} process(es)")


def pytest_unconfigure(config):
    if _OWN_SESSION_CACHE is not None:
        shutil.rmtree(_OWN_SESSION_CACHE, ignore_errors=True)


def _clear_lru_caches(module) -> None:
    for value in list(vars(module).values()):
        if (isinstance(value, functools._lru_cache_wrapper)
                and getattr(value, "__module__", None) == module.__name__):
            value.cache_clear()


def _release_compiled_code(test_module=None) -> None:
    """Drop JAX's compiled executables and traces, the kernel caches of fitlab and of the test
    module, and hand the freed heap back to the system. Derived models (fitlab.models: sums,
    layered models) stay cached: they are small, and the registry's caches are keyed on their
    identity. What is dropped is compiled again when needed (loaded from the session cache)."""
    jax.clear_caches()
    if test_module is not None:
        _clear_lru_caches(test_module)
    for name, module in list(sys.modules.items()):
        if (name == "fitlab" or name.startswith("fitlab.")) and not name.startswith("fitlab.models"):
            _clear_lru_caches(module)
    gc.collect()
    # what survives a release lives for the session (modules, the registry, the caches kept):
    # frozen, later collections do not walk it again (each full collection had walked the
    # whole heap: 7% of a test process's time)
    gc.freeze()
    try:
        ctypes.CDLL(None).malloc_trim(0)  # glibc: return freed arenas to the system
    except (OSError, AttributeError):
        pass


#: A test process whose resident memory is above this after a test, and has grown by
#: RELEASE_GROWTH_BYTES since its last release, releases its compiled code there and then (a
#: module that compiles many models would otherwise hold them all). The growth condition matters:
#: what a release cannot free (libraries, the allocator's arenas) kept a worker above the
#: threshold for good, and a release after every test then compiled every eager operation again
#: in every test (14,220 reloads from the session cache in one quick tier).
RELEASE_ABOVE_BYTES = 768 * 2**20
RELEASE_GROWTH_BYTES = 384 * 2**20
_AFTER_RELEASE = {"bytes": 0}


def _resident_bytes() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


@pytest.fixture(scope="module", autouse=True)
def _release_after_module(request):
    """After each test module, release its compiled code: without this the process kept every
    kernel any test had compiled (5.7 GB by the end of the quick tier)."""
    yield
    _release_compiled_code(request.module)
    _AFTER_RELEASE["bytes"] = _resident_bytes()


#: The modules whose quick cases tests/project/test_compiler_settings.py runs in a child session under
#: XLA's defaults (what users get).
DEFAULTS_CHECKED_MODULES = ("tests/models/test_model_contract.py",
                            "tests/models/test_hard_cases.py", "tests/models/test_sampling.py")
DEFAULTS_SESSION_TEST = "test_compiler_settings.py::test_contract_holds_under_xla_default_settings"


#: Each test module's measured seconds in the whole suite (FITLAB_RECORD_DURATIONS=1 rewrites it
#: from a run): modules run heaviest first, so that the two workers of ``--dist loadfile`` end
#: together (pyproject.toml turns xdist's own ordering, by number of tests, off).
MODULE_SECONDS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "module_seconds.json")
RECORD_ENV = "FITLAB_RECORD_DURATIONS"
_RECORDED: dict[str, float] = {}


def _heaviest_first(items) -> None:
    try:
        with open(MODULE_SECONDS, encoding="utf-8") as fh:
            seconds = json.load(fh)
    except (OSError, ValueError):
        return
    unknown = sorted(seconds.values())[len(seconds) // 2] if seconds else 0.0
    first = {}
    for k, item in enumerate(items):
        first.setdefault(item.nodeid.split("::")[0], k)
    items.sort(key=lambda i: (-seconds.get(i.nodeid.split("::")[0], unknown),
                              first[i.nodeid.split("::")[0]]))


def pytest_runtest_logreport(report):
    if os.environ.get(RECORD_ENV):
        module = report.nodeid.split("::")[0]
        _RECORDED[module] = _RECORDED.get(module, 0.0) + report.duration


@pytest.hookimpl(trylast=True)
def pytest_collection_finish(session):
    """The modules imported by collecting (JAX, fitlab, the test modules) live for the session:
    frozen, the cyclic collector does not walk them again (see tune_collector above)."""
    gc.collect()
    gc.freeze()


@pytest.hookimpl(trylast=True)  # after `-m`/`-k` have deselected: what is left decides
def pytest_collection_modifyitems(config, items):
    """Modules run heaviest first (MODULE_SECONDS). A session that runs slow tests leaves out
    their quick-tier samples (marked
    ``sample_of_slow``). A session that runs the child session under XLA's defaults (the whole
    suite) runs the quick cases of DEFAULTS_CHECKED_MODULES there only, under the settings users
    get, and not a second time at the tests' fast-compile settings: the same checks, compiled
    once. Their slow cases, and every case in a session without the child (the quick tier), run
    here."""
    _heaviest_first(items)
    if any(i.get_closest_marker("slow") is not None for i in items):
        _deselect(config, items, [i for i in items if i.get_closest_marker("sample_of_slow")])
    if not FAST_COMPILE or not any(i.nodeid.endswith(DEFAULTS_SESSION_TEST) for i in items):
        return
    root = str(config.rootpath)
    again = [i for i in items if i.get_closest_marker("slow") is None
             and os.path.relpath(str(i.path), root) in DEFAULTS_CHECKED_MODULES]
    _deselect(config, items, again)


def _deselect(config, items, drop) -> None:
    if drop:
        config.hook.pytest_deselected(items=drop)
        keep = set(map(id, drop))
        items[:] = [i for i in items if id(i) not in keep]


_OPTIMIZED = {"now": not FAST_COMPILE}


def _set_optimization(on: bool) -> None:
    """Compile at XLA's default optimization level (on) or without most optimizations (off),
    here and in the `fitlab` processes tests start; executables compiled the other way are
    dropped first, so that none is reused."""
    if _OPTIMIZED["now"] == on:
        return
    jax.clear_caches()
    jax.config.update("jax_disable_most_optimizations", not on)
    os.environ[NO_OPTIMIZATION_ENV] = "0" if on else "1"
    _OPTIMIZED["now"] = on


@pytest.fixture(autouse=True)
def _optimization_of_marked_tests(request):
    """A test marked ``optimized`` (its time goes into running compiled code) compiles at XLA's
    default optimization level; the others without most optimizations (TEST_XLA_FLAGS)."""
    if FAST_COMPILE:
        _set_optimization(request.node.get_closest_marker("optimized") is not None)
    yield


def _continues_optimized(item, nextitem) -> bool:
    """Whether the next test is an ``optimized`` one of the same module (no fixture of another
    scope is made between them, so the setting may stay)."""
    return (nextitem is not None and nextitem.module is item.module
            and nextitem.get_closest_marker("optimized") is not None)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item, nextitem):
    yield
    if FAST_COMPILE and _OPTIMIZED["now"] and not _continues_optimized(item, nextitem):
        # Module-scoped fixtures of the next test are made before its own setting applies: an
        # ``optimized`` test's setting must not carry over into them (a report built by a
        # fixture at XLA's default level and again by a test without most optimizations
        # differed in a figure's last digit).
        _set_optimization(False)
    if _resident_bytes() > max(RELEASE_ABOVE_BYTES, _AFTER_RELEASE["bytes"] + RELEASE_GROWTH_BYTES):
        _release_compiled_code(item.module)
        _AFTER_RELEASE["bytes"] = _resident_bytes()


#: Set by .ci/run: a test that would skip for a missing system package fails instead.
STRICT_ENV = "FITLAB_REQUIRE_ALL"


def skip_or_fail(reason: str):
    """Skip with ``reason`` on a developer machine; fail in CI (FITLAB_REQUIRE_ALL=1)."""
    if os.environ.get(STRICT_ENV, "") not in ("", "0"):
        pytest.fail(f"{reason} (and {STRICT_ENV} is set, so this is an error)")
    pytest.skip(reason)


@pytest.fixture(params=["float32", "float64"])
def dtype(request):
    import jax.numpy as jnp

    return jnp.dtype(request.param)


@pytest.fixture(scope="module")
def mitsuba_scalar():
    """Mitsuba 3 in its ``scalar_rgb`` variant (float32, needs no LLVM), the independent
    implementation the agreement tests compare with; the previous variant is restored after."""
    try:
        import mitsuba
    except ImportError as exc:
        skip_or_fail(f"mitsuba is not importable ({exc}); install the test extra: "
                     "pip install -e '.[test]'")
    previous = mitsuba.variant()
    try:
        mitsuba.set_variant("scalar_rgb")
    except Exception as exc:  # noqa: BLE001 - whatever the reason, there is nothing to compare
        skip_or_fail(f"mitsuba variant scalar_rgb unavailable ({exc})")
    yield mitsuba
    if previous is not None and previous != "scalar_rgb":
        mitsuba.set_variant(previous)
