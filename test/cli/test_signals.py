"""Signals and storage errors during writes: the bag commands clean up and say so in one line.

The commands run in child processes, as a user or a launcher starts them.
Where the signal must arrive at a known point of the work, the child sends it
to itself from the command's progress hook: no timing is involved.
"""

from __future__ import annotations

import os
import re
import resource
import signal
import socket
import subprocess
import sys
import textwrap

import pytest
from signalling import interrupt_while_importing

from marker_localizer.bag.io import BagWriter, sweep_staging
from marker_localizer.cli import main as cli

TIMEOUT_S = 120
#: A file-size limit that a small flight passes in its first frames, B.
FILE_SIZE_LIMIT_B = 1_500_000


def run_python(script, *args, **kwargs):
    """Run ``script`` in a fresh interpreter; return the CompletedProcess."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
        **kwargs,
    )


def entries(directory):
    return sorted(p.name for p in directory.iterdir())


SIMULATE_SIGNALLING_ITSELF = """
    import os, signal, sys
    from marker_localizer.cli.exits import run_command
    from marker_localizer.bag.record import record_flight
    from marker_localizer.synthetic.flight import FlightConfig, FlightSimulator

    out, signum, at_frame = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])

    def progress(done):
        if done == at_frame:
            os.kill(os.getpid(), signum)

    def body():
        simulator = FlightSimulator(FlightConfig(n_frames=6, width=160, height=120), seed=1)
        record_flight(simulator, out, progress=progress)
        return 0

    sys.exit(run_command("marker-localizer simulate", body))
"""


@pytest.mark.parametrize(
    "signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=["SIGTERM", "SIGINT", "SIGHUP"]
)
def test_a_signal_during_simulate_removes_the_unfinished_bag_and_exits_128_plus_it(
    tmp_path, signum
):
    result = run_python(SIMULATE_SIGNALLING_ITSELF, tmp_path / "flight", int(signum), 2)
    assert result.returncode == 128 + signum
    assert result.stderr == f"marker-localizer simulate: interrupted by {signum.name}\n"
    assert entries(tmp_path) == []


def test_sigterm_during_replay_removes_the_unfinished_output(small_flight, tmp_path):
    script = """
        import os, signal, sys
        from marker_localizer.cli.exits import run_command
        from marker_localizer.bag.replay import replay_bag

        def progress(done, total):
            if done == 3:
                os.kill(os.getpid(), signal.SIGTERM)

        sys.exit(run_command("marker-localizer replay",
                             lambda: replay_bag(sys.argv[1], sys.argv[2], progress=progress)))
    """
    result = run_python(script, small_flight, tmp_path / "out")
    assert result.returncode == 128 + signal.SIGTERM
    assert result.stderr == "marker-localizer replay: interrupted by SIGTERM\n"
    assert entries(tmp_path) == []


def test_a_second_signal_during_the_cleanup_cuts_it_short_in_one_line():
    script = """
        import os, signal, sys, time
        from marker_localizer.cli.exits import run_command

        def body():
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(60)
            finally:
                print("cleaning up", flush=True)
                os.kill(os.getpid(), signal.SIGTERM)  # a launcher's escalation
                time.sleep(60)
                print("cleaned up", flush=True)

        sys.exit(run_command("marker-localizer simulate", body))
    """
    result = run_python(script)
    assert result.returncode == 128 + signal.SIGTERM
    assert result.stdout == "cleaning up\n"
    assert result.stderr == "marker-localizer simulate: interrupted by SIGTERM\n"


def test_a_third_signal_ends_the_process_at_once_where_the_cleanup_still_hangs():
    script = """
        import os, signal, sys, time
        from marker_localizer.cli.exits import run_command

        def body():
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(60)
            finally:
                try:
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(60)
                finally:
                    print("still cleaning up", flush=True)
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(60)
                    print("cleaned up", flush=True)

        sys.exit(run_command("marker-localizer replay", body))
    """
    result = run_python(script)
    assert result.returncode == -signal.SIGINT
    assert result.stdout == "still cleaning up\n"
    assert result.stderr == ""


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_while_a_command_still_imports_is_one_line_and_128_plus_it(small_flight, signum):
    """Ctrl-C right after start: replay's imports (numpy, OpenCV, ROS) take seconds."""
    status, stdout, stderr = interrupt_while_importing(
        "numpy",
        "marker_localizer.cli:main",
        "replay",
        small_flight,
        "--out",
        small_flight.parent / "out",
        signum=signum,
    )
    assert (status, stdout) == (128 + signum, "")
    assert stderr == f"marker-localizer replay: interrupted by {signum.name}\n"
    assert not (small_flight.parent / "out").exists()


def test_a_second_signal_in_a_nested_block_leaves_the_default_action_past_the_outer_one():
    """The node serves in a block of its own inside the one that interrupts its start."""
    script = """
        import os, signal, threading
        from marker_localizer.stopping import interrupt, on_stop_signal

        stop = threading.Event()
        with on_stop_signal(interrupt, again=interrupt):
            with on_stop_signal(lambda signum: stop.set(), again=interrupt):
                os.kill(os.getpid(), signal.SIGINT)
                stop.wait(60)
            print("stopped", flush=True)
        print(signal.getsignal(signal.SIGINT) is signal.SIG_DFL, flush=True)
        os.kill(os.getpid(), signal.SIGINT)
        print("not reached", flush=True)
    """
    result = run_python(script)
    assert result.returncode == -signal.SIGINT
    assert result.stdout == "stopped\nTrue\n"


def test_the_node_stop_handler_sets_its_flag_once_and_the_second_signal_kills():
    script = """
        import os, signal, threading, time
        from marker_localizer.stopping import on_stop_signal

        stop = threading.Event()
        with on_stop_signal(lambda signum: stop.set()):
            os.kill(os.getpid(), signal.SIGINT)
            stop.wait(60)
            print("draining", flush=True)
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(60)
            print("drained", flush=True)
    """
    result = run_python(script)
    assert result.returncode == -signal.SIGINT
    assert result.stdout == "draining\n"


def test_after_a_stop_signal_the_second_ends_the_process_past_the_block_too():
    """The node says "stopped" and returns, and the interpreter's exit may still wait
    (for a worker pool: here a thread): a second Ctrl-C must end it there too."""
    script = """
        import os, signal, threading, time
        from marker_localizer.stopping import on_stop_signal

        stop = threading.Event()
        with on_stop_signal(lambda signum: stop.set()):
            os.kill(os.getpid(), signal.SIGINT)
            stop.wait(60)
        print("stopped", flush=True)
        threading.Thread(target=time.sleep, args=(20,)).start()  # the exit waits for it
        second = lambda: (time.sleep(0.5), os.kill(os.getpid(), signal.SIGINT))
        threading.Thread(target=second, daemon=True).start()
    """
    result = run_python(script)
    assert result.returncode == -signal.SIGINT
    assert result.stdout == "stopped\n"


def test_without_a_stop_signal_the_handlers_before_the_block_come_back():
    script = """
        import signal
        from marker_localizer.stopping import on_stop_signal

        def before(signum, frame):
            pass

        signal.signal(signal.SIGINT, before)  # whatever the shell left (nohup: ignored)
        with on_stop_signal(lambda signum: None):
            pass
        print(signal.getsignal(signal.SIGINT) is before)
    """
    assert run_python(script).stdout == "True\n"


def test_staging_of_a_killed_run_is_swept_by_the_next_one(tmp_path):
    killed = run_python(SIMULATE_SIGNALLING_ITSELF, tmp_path / "flight", int(signal.SIGKILL), 2)
    assert killed.returncode == -signal.SIGKILL
    (left,) = entries(tmp_path)
    assert left.startswith(f".flight.partial-{socket.gethostname()}-")
    live = tmp_path / f".other.partial-{socket.gethostname()}-{os.getpid()}"
    elsewhere = tmp_path / ".other.partial-another-host-1"
    live.mkdir()
    elsewhere.mkdir()
    assert (
        cli(
            [
                "simulate",
                "--out",
                str(tmp_path / "next"),
                "--frames",
                "1",
                "--width",
                "64",
                "--height",
                "48",
                "--cameras",
                "1",
            ]
        )
        == 0
    )
    assert entries(tmp_path) == sorted([live.name, elsewhere.name, "next"])
    assert sweep_staging(tmp_path) == []


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_storage_error_during_simulate_is_one_line_and_leaves_nothing(tmp_path, storage):
    """RLIMIT_FSIZE makes the kernel refuse the write, as a full disk does (EFBIG for ENOSPC)."""

    def limit_file_size():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # fail the write instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_SIZE_LIMIT_B, FILE_SIZE_LIMIT_B))

    out = tmp_path / "flight"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "marker_localizer.cli",
            "simulate",
            "--out",
            str(out),
            "--frames",
            "8",
            "--width",
            "320",
            "--height",
            "240",
            "--storage",
            storage,
        ],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
        preexec_fn=limit_file_size,
    )
    assert result.returncode == 1
    # mcap: the OS's words; sqlite: its own (at a write or at the final commit).
    error = r"cannot (write|finish bag) \((File too large|disk I/O error)\)"
    assert re.fullmatch(
        f"marker-localizer simulate: error: {re.escape(str(out))}: {error}\n", result.stderr
    ), result.stderr
    assert entries(tmp_path) == []


def test_writer_refuses_nothing_it_did_not_create(tmp_path):
    """The sweep leaves alone what does not look like a staging directory of this host."""
    for name in ("notes.partial-1", ".flight.partial-x", f".f.partial-{socket.gethostname()}-x"):
        (tmp_path / name).mkdir()
    with BagWriter(tmp_path / "bag") as bag:
        bag.add_topic("/a", "std_msgs/msg/String")
    assert "bag" in entries(tmp_path) and len(entries(tmp_path)) == 4
