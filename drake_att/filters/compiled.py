"""What the compiled filter kernels share: numba's ``njit`` with its on-disk cache where it can
have one, and the scalar quaternion building blocks.

:func:`jit` is ``numba.njit(cache=True)``: the first call of a kernel in a fresh environment
compiles it and writes the machine code to numba's cache (``__pycache__`` next to the module,
or, where that is not writable, the user-wide cache ``~/.cache/numba`` / ``$NUMBA_CACHE_DIR``);
later processes load it. Where numba finds no writable cache location at all (it raises
``RuntimeError`` at decoration), the kernels are compiled in every process instead, with no
warning and no error: :data:`CACHING` says which. A cache file that cannot be written when a
kernel is first compiled (a full disk, a quota, a file-size limit) is skipped: the kernel runs
compiled in that process and the run goes on. No ``fastmath``: IEEE semantics, as numpy.

Compiling is not silent: the first compilation in a process prints one line to stderr
(:data:`COMPILE_MESSAGE`; numba reports compilations, not cache loads), so a first run after
install or after a kernel changed says why it is slow.

The helpers take and return floats (tuples for quaternions, ``w`` first) and repeat
:mod:`drake_att.rotations`' scalar formulas exactly, so kernels built on them agree with the
numpy code to round-off.
"""

from __future__ import annotations

import math
import sys

import numba
from numba.core import event as _numba_event

from drake_att.rotations import _SMALL_ANGLE  # series of sin(a/2)/a below it, as rotvec_to_quat

CACHING = True
COMPILE_MESSAGE = (
    "drake_att: compiling numba kernels for their first use (seconds to a minute, once: "
    "later runs load them from numba's on-disk cache)"
)


class _FirstCompileNotice(_numba_event.Listener):
    """Prints :data:`COMPILE_MESSAGE` at the process's first numba compilation of a drake_att
    function (another package's numba functions are not ours to announce)."""

    said = False

    def on_start(self, ev) -> None:
        dispatcher = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
        module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
        if not _FirstCompileNotice.said and module.split(".")[0] == "drake_att":
            _FirstCompileNotice.said = True
            print(
                COMPILE_MESSAGE if CACHING else COMPILE_MESSAGE.split(" (")[0] + " (no writable cache: every run)",
                file=sys.stderr,
                flush=True,
            )

    def on_end(self, ev) -> None:
        pass


_numba_event.register("numba:compile", _FirstCompileNotice())


def jit(func=None, **options):
    """``numba.njit(cache=True, **options)``, or ``numba.njit(**options)`` without the on-disk
    cache where numba finds no writable cache directory (see the module docstring). As
    ``@jit`` or, with numba's options (e.g. ``inline="always"``), ``@jit(**options)``."""
    global CACHING
    if func is None:
        return lambda f: jit(f, **options)
    try:
        return _saving_tolerantly(numba.njit(cache=True, **options)(func))
    except RuntimeError:
        CACHING = False
        return numba.njit(**options)(func)


def _saving_tolerantly(dispatcher):
    """``dispatcher`` whose cache writes give up on ``OSError`` instead of failing the call
    that compiled the kernel (numba's cache object is internal: left as it is if absent)."""
    cache = getattr(dispatcher, "_cache", None)
    save = getattr(cache, "save_overload", None)
    if save is None:
        return dispatcher

    def save_overload(sig, data):
        try:
            save(sig, data)
        except OSError:
            pass  # kept in memory for this process; a later process compiles and tries again

    cache.save_overload = save_overload
    return dispatcher


@jit
def rotvec_to_quat(x, y, z):
    """rotations.rotvec_to_quat: ``exp(phi / 2)``."""
    a = math.sqrt(x * x + y * y + z * z)
    half = 0.5 * a
    if a < _SMALL_ANGLE:
        k = 0.5 - a * a / 48.0
    else:
        k = math.sin(half) / a
    return math.cos(half), k * x, k * y, k * z


@jit
def quat_multiply(pw, px, py, pz, qw, qx, qy, qz):
    """rotations.quat_multiply (Hamilton product ``p ⊗ q``)."""
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


__all__ = ["CACHING", "jit", "rotvec_to_quat", "quat_multiply"]
