"""Signals sent to a command at a known point of its start, without timing.

The command runs in a child interpreter whose import of a given module says so
on stdout and then waits there: a signal sent once that line is read arrives
while the command is still importing, however fast or slow the machine.
"""

import signal
import subprocess
import sys
import textwrap

TIMEOUT_S = 120

_IMPORT_WAITING_FOR_A_SIGNAL = """
    import importlib.abc, sys, time

    waiting_at = sys.argv[1]

    class Waiting(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == waiting_at:
                print("importing", name, flush=True)
                time.sleep(60)
            return None

    sys.meta_path.insert(0, Waiting())
    module, function = sys.argv[2].split(":")
    sys.argv = sys.argv[2:]
    sys.exit(getattr(__import__(module, fromlist=[function]), function)())
"""


def interrupt_while_importing(module, entry_point, *args, signum=signal.SIGINT):
    """Run a console script's ``entry_point`` (``"package.module:function"``) with ``args``.

    ``signum`` is sent while the script imports ``module`` (its first import of it).

    Returns:
        (exit status, stdout after the line that said so, stderr).
    """
    process = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(_IMPORT_WAITING_FOR_A_SIGNAL),
            module,
            entry_point,
            *map(str, args),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout.readline() == f"importing {module}\n"
        process.send_signal(signum)
        stdout, stderr = process.communicate(timeout=TIMEOUT_S)
    finally:
        process.kill()
    return process.returncode, stdout, stderr
