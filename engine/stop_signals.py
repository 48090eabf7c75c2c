"""How the command line stops on a signal: SIGINT (Ctrl-C), SIGTERM and SIGHUP (what render farm managers and
a closed terminal send) alike.

The first signal asks the render to stop (session.request_cancel, which every final render polls): the frame
in progress is dropped, the frames finished before it are kept (a frame being saved is saved), and the
command exits with 128 + the signal's number, as a shell reports a process the signal ended (130, 143, 129),
after one line on stderr. A second signal quits at once, after removing the temporary file of a save in
progress (`saving`): one line, no traceback. Ember's worker processes ignore these signals (a signal sent to
the process group reaches them too) and leave when this process closes their pipes.

Handlers restart interrupted system calls (SA_RESTART): a signal that arrives while Blender's C code writes a
frame does not fail the write. A local Ray (--ray local) is started with the signals held, so that its
processes do not get them either (engine/distributed.py).
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys

from .session import cancel_requested, clear_cancel, request_cancel

STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))

_received: int | None = None    # the signal that asked the render to stop
_saving: str | None = None      # the temporary file a save is writing


def install() -> dict:
    """Handle the stop signals (see the module); returns the handlers they had, for restore()."""
    global _received
    _received = None
    clear_cancel()
    previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    take_back()
    return previous


def restore(previous: dict) -> None:
    for sig, handler in previous.items():
        signal.signal(sig, handler)


def _handler(signum, frame) -> None:
    global _received
    if cancel_requested():
        _quit_now(signum)
    _received = signum
    request_cancel()


def _quit_now(signum: int) -> None:
    """A second signal: no waiting for the frame in progress, nor for anything else."""
    if _saving is not None and os.path.exists(_saving):
        os.remove(_saving)
    sys.stdout.flush()
    print(f"ember: {_name(signum)} again: quit at once; the frame in progress is not saved", file=sys.stderr,
          flush=True)
    os._exit(128 + signum)


def stopped() -> bool:
    """Whether a signal (or Esc's equivalent, session.request_cancel) asked the render to stop."""
    return cancel_requested()


def exit_status() -> int:
    """128 + the signal that stopped the render (SIGINT when none was received: a stop asked otherwise)."""
    return 128 + (_received or signal.SIGINT)


def interrupted_by() -> str:
    """'interrupted' for Ctrl-C, 'interrupted by SIGTERM' for the others: the start of the stop's line."""
    return "interrupted" if _received in (None, signal.SIGINT) else f"interrupted by {_name(_received)}"


def _name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def take_back() -> None:
    """Handle the stop signals again after a library replaced the handlers (ray.init installs its own for
    SIGTERM: an exit with status 1, a stack dump)."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, _handler)
        if hasattr(signal, "siginterrupt"):   # POSIX
            signal.siginterrupt(sig, False)


@contextlib.contextmanager
def held():
    """The stop signals held (blocked) in the block: one that arrives waits for its end. Processes started in
    the block inherit the block and never get them: a signal sent to the process group then reaches this
    process alone, which stops them in order."""
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS) if hasattr(signal, "pthread_sigmask") else None
    try:
        yield
    finally:
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)


@contextlib.contextmanager
def saving_to(make_file):
    """Create the temporary file of a save with make_file() -> (fd, path) and register it for _quit_now (the
    stop signals held meanwhile: none can fall between its creation and its registration). Yields its fd
    and path; unregisters it at the end of the block."""
    global _saving
    with held():
        fd, path = make_file()
        _saving = path
    try:
        yield fd, path
    finally:
        _saving = None
