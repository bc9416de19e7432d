"""The simulator's engine: Dr.Jit and Mitsuba 3 on a device, with a libLLVM that works.

:func:`load` returns an :class:`Engine` (the ``drjit`` module, the ``mitsuba`` module with its
variant set, the backend and the libLLVM the process loaded). Dr.Jit's CPU backend (variant
``llvm_ad_rgb``) needs a libLLVM shared library at run time; :func:`select_libllvm` picks it, in
this order, before ``drjit`` is first imported:

1. ``DRJIT_LIBLLVM_PATH`` when set (Dr.Jit's own variable; it wins over ``FITLAB_LLVM``): that
   file, or an error naming it;
2. the system's, found as Dr.Jit 1.5 finds it (:func:`system_libllvm`), skipped when the
   environment variable ``FITLAB_LLVM=pip`` (so CI can prove the pip path on a machine that has a
   system libLLVM);
3. the pip package ``karellen-llvm-core`` (a core dependency on Linux x86-64).

The choice of 2 or 3 is handed to Dr.Jit through ``DRJIT_LIBLLVM_PATH`` in ``os.environ``: Dr.Jit
starts its backends in a thread at ``import drjit`` and reads the variable there, once per process.

A library older than LLVM :data:`MIN_LLVM` is passed over: Dr.Jit 1.5 refuses LLVM < 15, and
LLVM 15 and 16 abort the process ("LLVM ERROR: Cannot select ... fmaximum") on Mitsuba's BSDF
kernels. If ``drjit`` was imported before :func:`load` (a test that imported ``mitsuba``), the
choice was Dr.Jit's own: :func:`load` reports the library it loaded, or says how to fix it.
Whatever cannot load raises :class:`fitlab.errors.FitlabError` with one line naming what to
install. Engines are cached per device.
"""

from __future__ import annotations

import glob
import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
from typing import Any, NamedTuple

from fitlab.errors import FitlabError
from fitlab.simulate.protocol import DEVICES

#: Oldest LLVM major version that compiles Mitsuba 3.9's kernels through Dr.Jit 1.5 (16 aborts).
MIN_LLVM = 17
#: Dr.Jit's variable naming the libLLVM to load; fitlab sets it to the system or pip one it picks.
ENV_PATH = "DRJIT_LIBLLVM_PATH"
#: ``FITLAB_LLVM=pip`` skips the system's libLLVM (unset or ``auto``: the order above).
ENV_MODE = "FITLAB_LLVM"
#: The pip package that ships a libLLVM (``lib/libLLVM.so.*`` beside the environment's Python).
PIP_PACKAGE = "karellen-llvm-core"
INSTALL_HINT = ("pip install karellen-llvm-core (or apt-get install libllvm19), "
                f"or set {ENV_PATH}")
VARIANTS = {"llvm": "llvm_ad_rgb", "cuda": "cuda_ad_rgb"}

#: Dr.Jit 1.5's glob for libLLVM on Linux (drjit-core src/llvm_api.cpp).
_SYSTEM_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib/wsl/lib")
#: Names of the library itself: libLLVM-15.so.1, libLLVM-14.0.6.so.1, libLLVM-17.so,
#: libLLVM.so.19.1 (not libLLVMSPIRVLib.so.15, which the glob also matches).
_NAME = re.compile(r"libLLVM(?:-(\d+)[\d.]*\.so(?:\.\d+)*|\.so(?:\.(\d+)(?:\.\d+)*)?)")
#: Process-wide state (a plain dict, not functools.cache: the tests clear those between modules):
#: the engine per device, and select_libllvm's answer under "libllvm".
_ENGINES: dict[str, Engine] = {}
_CHOICE: dict[str, tuple[str, str]] = {}


class Engine(NamedTuple):
    """Dr.Jit and Mitsuba ready on one backend.

    ``dr``: the ``drjit`` module; ``mi``: the ``mitsuba`` module with ``variant`` set
    (``llvm_ad_rgb`` or ``cuda_ad_rgb``); ``backend``: ``llvm`` or ``cuda``; ``libllvm``: the path
    of the libLLVM the process loaded (None on cuda); ``libllvm_source``: where it came from,
    ``DRJIT_LIBLLVM_PATH``, ``system`` or ``pip`` (None on cuda)."""

    dr: Any
    mi: Any
    variant: str
    backend: str
    libllvm: str | None
    libllvm_source: str | None


def load(device: str = "auto") -> Engine:
    """Dr.Jit and Mitsuba on ``device``: ``auto`` (CUDA when Dr.Jit has a usable GPU, else the
    CPU's LLVM backend), ``cpu`` (LLVM) or ``gpu`` (CUDA, else an error). Cached per device; a
    cached engine's variant is set again if someone changed Mitsuba's since. Raises
    :class:`fitlab.errors.FitlabError` (one line: what to install) when it cannot load."""
    if device not in DEVICES:
        raise FitlabError(f"device must be one of {', '.join(DEVICES)}, not {device!r}")
    engine = _ENGINES.get(device)
    if engine is None:
        engine = _ENGINES[device] = _load(device)
    if engine.mi.variant() != engine.variant:
        engine.mi.set_variant(engine.variant)
    return engine


def _load(device: str) -> Engine:
    """:func:`load` without the cache."""
    choice, problem = None, None
    # A choice counts if made before drjit started its backends (now, or earlier: kept).
    if "drjit" not in sys.modules or _CHOICE:
        try:
            choice = select_libllvm()
        except FitlabError as exc:  # the GPU needs no libLLVM: raise only if LLVM is wanted
            if device == "cpu":
                raise
            problem = exc
    dr, mi = _import_modules()
    if device != "cpu" and dr.has_backend(dr.JitBackend.CUDA):
        return _with_variant(Engine(dr, mi, VARIANTS["cuda"], "cuda", None, None))
    if device == "gpu":
        raise FitlabError("no GPU for the simulator: Dr.Jit found no NVIDIA GPU with a working "
                          "driver (libcuda.so); install the NVIDIA driver or use --device cpu")
    if problem is not None:
        raise problem
    path, source = _loaded_libllvm(dr, choice)
    return _with_variant(Engine(dr, mi, VARIANTS["llvm"], "llvm", path, source))


def gpu_available() -> bool:
    """Whether Dr.Jit has a usable CUDA backend (a GPU with a working driver)."""
    try:
        select_libllvm()
    except FitlabError:
        pass
    dr, _ = _import_modules()
    return bool(dr.has_backend(dr.JitBackend.CUDA))


def _import_modules():
    """The ``drjit`` and ``mitsuba`` modules, or a one-line error saying what to install."""
    try:
        import drjit
        import mitsuba
    except ImportError as exc:
        raise FitlabError(f"the simulator needs Mitsuba 3 and Dr.Jit ({_first_line(exc)}): "
                          "pip install mitsuba drjit") from None
    return drjit, mitsuba


def _with_variant(engine: Engine) -> Engine:
    """``engine`` after setting its Mitsuba variant (an error if this Mitsuba lacks it)."""
    if engine.variant not in engine.mi.variants():
        raise FitlabError(f"this Mitsuba build has no {engine.variant} variant: "
                          "pip install 'mitsuba>=3.9,<3.10'")
    engine.mi.set_variant(engine.variant)
    return engine


def select_libllvm() -> tuple[str, str]:
    """Choose the libLLVM for Dr.Jit's CPU backend: ``(path, source)`` with ``source`` one of
    ``DRJIT_LIBLLVM_PATH``, ``system``, ``pip`` (the order of the module docstring). Points
    ``DRJIT_LIBLLVM_PATH`` at a system or pip choice (so Dr.Jit loads the file checked here, and
    child processes inherit it), hence call it before ``drjit`` (or ``mitsuba``) is imported;
    once per process (the first answer is kept). Raises
    :class:`fitlab.errors.FitlabError` when there is none or the one named is unusable."""
    if "libllvm" not in _CHOICE:
        _CHOICE["libllvm"] = _select_libllvm()
    return _CHOICE["libllvm"]


def _select_libllvm() -> tuple[str, str]:
    """:func:`select_libllvm` without its memory."""
    mode = os.environ.get(ENV_MODE, "").strip().lower() or "auto"
    if mode not in ("auto", "pip"):
        raise FitlabError(f"{ENV_MODE} must be 'pip' (only the pip package {PIP_PACKAGE}) or "
                          f"unset, not {mode!r}")
    given = os.environ.get(ENV_PATH, "")
    if given:  # Dr.Jit reads an empty value as unset too
        if not os.path.isfile(given):
            raise FitlabError(f"{ENV_PATH}={given}: no such file; point it at a libLLVM "
                              f"(LLVM {MIN_LLVM} or newer) or unset it")
        if not _recent(given):
            raise FitlabError(f"{ENV_PATH}={given} is LLVM {llvm_major(given)}; the simulator "
                              f"needs LLVM {MIN_LLVM} or newer: {INSTALL_HINT}")
        return given, ENV_PATH
    too_old = []
    if mode == "auto":
        for path in system_libllvm():
            if _recent(path):
                os.environ[ENV_PATH] = path  # Dr.Jit's glob may match other files
                return path, "system"
            too_old.append(f"LLVM {llvm_major(path)} at {path}")
    path = pip_libllvm()
    if path is not None:
        os.environ[ENV_PATH] = path
        return path, "pip"
    if mode == "pip":
        raise FitlabError(f"{ENV_MODE}=pip but the pip package {PIP_PACKAGE} is not installed: "
                          f"pip install {PIP_PACKAGE}")
    found = f" (found only {', '.join(too_old)}, too old)" if too_old else ""
    raise FitlabError(f"the simulator needs libLLVM {MIN_LLVM} or newer for Dr.Jit's CPU "
                      f"backend{found}: {INSTALL_HINT}")


def system_libllvm() -> list[str]:
    """The system's libLLVM files in Dr.Jit 1.5's order of preference (drjit-core
    src/llvm_api.cpp and ``jitc_find_library`` in src/init.cpp): ``libLLVM.so`` where the dynamic
    loader finds it (``LD_LIBRARY_PATH``, ``ld.so.cache``, the default folders), then
    ``/usr/lib/{x86_64-linux-gnu,aarch64-linux-gnu,wsl/lib}/libLLVM*.so.*`` newest first (Dr.Jit
    loads the newest, regular files before symbolic links). One path per distinct file."""
    found = [] if (hit := _dynamic_loader_path("libLLVM.so")) is None else [hit]
    paths = [p for d in _SYSTEM_DIRS for p in glob.glob(os.path.join(d, "libLLVM*.so.*"))
             if _NAME.fullmatch(os.path.basename(p))]
    files = [p for p in paths if not os.path.islink(p)] or paths
    found += sorted(files, key=_version_key, reverse=True)
    unique, seen = [], set()
    for path in found:
        real = os.path.realpath(path)
        if real not in seen:
            seen.add(real)
            unique.append(path)
    return unique


def pip_libllvm() -> str | None:
    """The libLLVM of the pip package ``karellen-llvm-core`` (found through its file list in
    ``importlib.metadata``), or None when the package is not installed."""
    try:
        dist = importlib.metadata.distribution(PIP_PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        return None
    paths = [os.path.normpath(str(dist.locate_file(f))) for f in dist.files or ()
             if _NAME.fullmatch(f.name)]
    files = [p for p in paths if os.path.isfile(p) and not os.path.islink(p)]
    return max(files, key=_version_key) if files else None


def llvm_major(path: str) -> int | None:
    """The LLVM major version in a libLLVM's file name (or its target's, for a symbolic link),
    e.g. 15 for ``libLLVM-15.so.1``, 23 for ``libLLVM.so.23.1``; None when the name has none."""
    for name in (os.path.basename(path), os.path.basename(os.path.realpath(path))):
        m = _NAME.fullmatch(name)
        if m and (m.group(1) or m.group(2)):
            return int(m.group(1) or m.group(2))
    return None


def _recent(path: str) -> bool:
    """Whether ``path`` is LLVM :data:`MIN_LLVM` or newer (an unnamed version passes; Dr.Jit's
    version, checked after loading, decides)."""
    major = llvm_major(path)
    return major is None or major >= MIN_LLVM


def _loaded_libllvm(dr, choice: tuple[str, str] | None) -> tuple[str | None, str]:
    """``(path, source)`` of the libLLVM Dr.Jit's CPU backend runs on (from ``/proc/self/maps``),
    ``choice`` being :func:`select_libllvm`'s or None when ``drjit`` was imported before it. Raises
    when the backend is down or its LLVM too old."""
    pip = pip_libllvm()
    advice = INSTALL_HINT if choice else (
        "drjit was imported before fitlab could choose a libLLVM: call "
        "fitlab.simulate.engine.load before importing mitsuba or drjit, or set "
        + (f"{ENV_PATH}={pip}" if pip else f"{ENV_PATH} ({INSTALL_HINT})"))
    if not dr.has_backend(dr.JitBackend.LLVM):
        tried = f" with {choice[0]} ({choice[1]})" if choice else ""
        raise FitlabError(f"Dr.Jit's CPU backend did not start{tried}: {advice}")
    major = dr.detail.llvm_version()[0]
    mapped = _mapped_libllvm()
    same = [p for p in mapped if choice and _same_file(p, choice[0])]
    by_version = [p for p in mapped if llvm_major(p) == major]
    path = (same or by_version or mapped or [choice[0] if choice else None])[0]
    if major < MIN_LLVM:
        raise FitlabError(f"Dr.Jit loaded LLVM {major} ({path}), which cannot compile Mitsuba's "
                          f"kernels (LLVM {MIN_LLVM} or newer needed); {advice}")
    if choice:
        return path, choice[1]
    given = os.environ.get(ENV_PATH, "")
    if given and path and _same_file(given, path):
        return path, ENV_PATH
    return path, "pip" if pip and path and _same_file(pip, path) else "system"


def _mapped_libllvm() -> list[str]:
    """The libLLVM files mapped into this process (``/proc/self/maps``), in order of address."""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
            paths = [line.split(None, 5)[-1].strip() for line in maps if "libLLVM" in line]
    except OSError:
        return []
    return list(dict.fromkeys(p for p in paths if _NAME.fullmatch(os.path.basename(p))))


def _dynamic_loader_path(name: str) -> str | None:
    """Where ``dlopen(name)`` would find a library: ``LD_LIBRARY_PATH``, then ``ld.so.cache``
    (``ldconfig -p``), then the default folders; None if nowhere."""
    for folder in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep):
        if folder and os.path.isfile(os.path.join(folder, name)):
            return os.path.join(folder, name)
    ldconfig = shutil.which("ldconfig") or next(
        (p for p in ("/sbin/ldconfig", "/usr/sbin/ldconfig") if os.path.isfile(p)), None)
    if ldconfig:
        try:
            listing = subprocess.run([ldconfig, "-p"], capture_output=True, text=True,
                                     timeout=10, check=False).stdout
        except (OSError, subprocess.SubprocessError):
            listing = ""
        for line in listing.splitlines():
            entry, _, target = line.strip().partition(" => ")
            if entry.split(" ", 1)[0] == name and os.path.isfile(target):
                return target
    for folder in ("/lib64", "/usr/lib64", "/lib", "/usr/lib"):
        if os.path.isfile(os.path.join(folder, name)):
            return os.path.join(folder, name)
    return None


def _version_key(path: str) -> tuple:
    """Sort key of a libLLVM: its major version, then its name with numbers compared as numbers
    (libLLVM-14.0.6.so.1 < libLLVM-15.so.1 < libLLVM.so.19.1)."""
    parts = re.split(r"(\d+)", os.path.basename(path))
    return llvm_major(path) or -1, tuple(int(p) if i % 2 else p for i, p in enumerate(parts))


def _same_file(a: str, b: str) -> bool:
    """Whether two paths name one file (False if either is missing)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _first_line(exc: BaseException) -> str:
    """The first non-empty line of an exception's message."""
    return next((line.strip() for line in str(exc).splitlines() if line.strip()),
                type(exc).__name__)
