"""SIGINT, SIGTERM and SIGHUP stop every long-running command alike; a second stops it at once.

Service managers and ``ros2 launch`` send SIGTERM (launch: SIGINT, then SIGTERM
5 s later, then SIGKILL 5 s after that), a user presses Ctrl-C, a closed terminal
or a dropped ssh session sends SIGHUP: the first of any starts a clean stop (the
node drains its frames in flight, a bag command removes its unfinished output).
A second one, while that stop is under way, stops at once: it interrupts
whatever the stop is waiting for (the frames in flight are abandoned, their
worker processes ended), the process still tidies up what is its own (shared
memory, worker processes: nothing is left for Python's resource tracker to warn
about) and exits 128 + the signal's number
with one line naming it (:func:`run_interruptible`). A third, or a second where
no second action is given, has the signals' default action: it ends the
process where it stands, even where the stop hangs; what that leaves behind (a
bag's staging directory) is swept by the next run. (Python runs the first two
handlers in the main thread when it next runs Python code: a wait inside a C
call delays them, so ``play`` waits for acknowledgements in calls of 0.1 s at
most; the third is the kernel's.)

Ctrl-C before the command is ready (while it imports) is the same single line:
the entry points install the handlers before their heavy imports.
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import NoReturn

#: The signals that stop a command. SIGHUP's default action would end the process
#: without a stop, and with the worker processes' resource tracker, their shared
#: memory left in /dev/shm for good.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

#: Stop signals handled in this process so far, by any :func:`on_stop_signal` block
#: (a block nested in another tells the outer one so).
_handled = [0]


class Interrupted(KeyboardInterrupt):
    """A stop signal arrived: unwind (writers remove their staging), then exit.

    A KeyboardInterrupt, so that every ``except KeyboardInterrupt`` and
    ``finally`` treats SIGTERM (what service managers and ``ros2 launch``
    send) as it treats Ctrl-C.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def interrupt(signum: int) -> NoReturn:
    """Raise :class:`Interrupted` for ``signum``: an action for :func:`on_stop_signal`."""
    raise Interrupted(signum)


def _set_handlers(handler: Callable[[int, object], None] | int) -> None:
    for stop in STOP_SIGNALS:
        signal.signal(stop, handler)


@contextmanager
def on_stop_signal(
    action: Callable[[int], None], again: Callable[[int], None] | None = None
) -> Iterator[None]:
    """Within the block, call ``action(signum)`` on the first SIGINT or SIGTERM.

    Args:
        action: called with the first signal's number; may raise (the exception
            then unwinds the main thread from where it was).
        again: called with the second signal's number, if it comes while the
            block still runs (:func:`interrupt`: stop at once); None gives the
            second signal its default action at once.

    After the signals the block handles, both signals have their default action
    for the rest of the process, past the block too: the process may still be
    stopping after it (the interpreter's exit waits for a worker pool), and a
    further signal must end it there. Outside the main thread, where Python
    cannot install handlers, the block runs with the handlers as they are.
    Where no signal came (here or in a block nested in this one), the handlers
    in place before are put back at the block's end.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    handled_before = _handled[0]

    def second(signum: int, _frame: object) -> None:
        _set_handlers(signal.SIG_DFL)
        _handled[0] += 1
        assert again is not None
        again(signum)

    def first(signum: int, _frame: object) -> None:
        _set_handlers(signal.SIG_DFL if again is None else second)
        _handled[0] += 1
        action(signum)

    previous = {stop: signal.signal(stop, first) for stop in STOP_SIGNALS}
    try:
        yield
    finally:
        if _handled[0] == handled_before:
            for stop, handler in previous.items():
                signal.signal(stop, handler)
        else:
            _set_handlers(signal.SIG_DFL)


def interrupted_status(label: str, err: KeyboardInterrupt) -> int:
    """Say on stderr, in one line, which signal interrupted ``label``; return its exit status.

    Args:
        label: what starts the line: ``"marker-localizer replay"``.
        err: the interruption; a plain KeyboardInterrupt is Ctrl-C (Python's own handler).

    Returns:
        128 + the signal's number: 130 for SIGINT, 143 for SIGTERM.
    """
    signum = err.signum if isinstance(err, Interrupted) else signal.SIGINT
    sys.stderr.write(f"{label}: interrupted by {signal.Signals(signum).name}\n")
    return 128 + signum


def run_interruptible(label: str, body: Callable[[], int]) -> int:
    """Run ``body`` where SIGINT and SIGTERM interrupt it; its exit status.

    The first signal raises :class:`Interrupted` in the main thread, so that
    ``body`` unwinds (its ``finally`` clauses tidy up); a second one during
    that raises again, cutting the tidying short where it waits; a third ends
    the process (module docstring). ``body`` may handle the signals its own way
    in a nested :func:`on_stop_signal` block (the node serves until the first).

    Args:
        label: what starts the line that names the signal.
        body: the command; returns its exit status.

    Returns:
        ``body``'s status, or 128 + the signal's number after one line on stderr
        (:func:`interrupted_status`).
    """
    try:
        with on_stop_signal(interrupt, again=interrupt):
            return body()
    except KeyboardInterrupt as err:
        return interrupted_status(label, err)
