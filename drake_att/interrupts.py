"""Ctrl-C that is never lost.

Python raises ``KeyboardInterrupt`` at the main thread's next bytecode after a SIGINT. When
that bytecode belongs to a finalizer or a weakref callback (run by the garbage collector at
any moment, e.g. a ``WeakKeyDictionary``'s clean-up), the interpreter prints "Exception
ignored in ..." and swallows the interrupt: a campaign would run to its end and exit 0.
While :func:`remembered` is active, the SIGINT handler also marks the interrupt, and
:func:`raise_if_interrupted` raises it again at the campaign's checkpoints (after each run,
before the report). The mark is cleared when a ``KeyboardInterrupt`` leaves the block.
"""

from __future__ import annotations

import contextlib
import functools
import signal
import threading

_state = {"pending": False, "depth": 0}


def _on_sigint(signum, frame):
    _state["pending"] = True
    raise KeyboardInterrupt


@contextlib.contextmanager
def remembered():
    """Remember every Ctrl-C inside the block (see the module docstring). Only in the main
    thread and only over Python's default SIGINT handler: another handler (a worker's
    ``SIG_IGN``, a user's own) is left alone. Nested blocks share the outer one's mark."""
    outermost = (
        _state["depth"] == 0
        and threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    )
    previous = signal.signal(signal.SIGINT, _on_sigint) if outermost else None
    if outermost:
        _state["pending"] = False
    _state["depth"] += 1
    try:
        yield
    except KeyboardInterrupt:
        _state["pending"] = False  # delivered
        raise
    finally:
        _state["depth"] -= 1
        if outermost:
            signal.signal(signal.SIGINT, previous)
            _state["pending"] = False


def remembering(func):
    """``func`` run inside :func:`remembered` (a campaign's entry points)."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with remembered():
            return func(*args, **kwargs)

    return wrapper


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` if a Ctrl-C inside :func:`remembered` was swallowed."""
    if _state["pending"]:
        _state["pending"] = False
        raise KeyboardInterrupt
