"""SIGINT and SIGTERM stop every long-running command the same way; a second one ends it.

Service managers and ``ros2 launch`` send SIGTERM (launch: SIGINT, then SIGTERM
5 s later, then SIGKILL 5 s after that), a user presses Ctrl-C: the first of
either starts a clean stop (the node drains its frames in flight, a bag
command removes its unfinished output). The handler then gives both signals
back their default action, so a second one ends the process at once even
where the clean stop hangs; what it leaves behind (a bag's staging directory)
is swept by the next run.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

#: The signals that stop a command.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def on_stop_signal(action: Callable[[int], None]) -> Iterator[None]:
    """Within the block, call ``action(signum)`` on the first SIGINT or SIGTERM.

    ``action`` may raise (the exception then unwinds the main thread from where
    it was). Outside the main thread, where Python cannot install handlers,
    the block runs with the handlers as they are. The handlers in place before
    are put back at the block's end unless a signal came: then both keep their
    default action, for the rest of the process.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    stopped = threading.Event()

    def first(signum: int, _frame: object) -> None:
        for stop in STOP_SIGNALS:
            signal.signal(stop, signal.SIG_DFL)
        stopped.set()
        action(signum)

    previous = {stop: signal.signal(stop, first) for stop in STOP_SIGNALS}
    try:
        yield
    finally:
        # After a first signal the defaults stay: the process may still be stopping
        # after the block (the interpreter's exit waits for a worker pool), and a
        # second signal must end it there too.
        if not stopped.is_set():
            for stop, handler in previous.items():
                signal.signal(stop, handler)
