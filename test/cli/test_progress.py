"""The progress bar of the long commands: drawn on a terminal only, total learnt on the way."""

import io

from marker_localizer.cli.progress import ProgressBar


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_bar_draws_only_on_a_terminal():
    terminal, pipe = Terminal(), io.StringIO()
    for stream in (terminal, pipe):
        bar = ProgressBar(4, "replay", stream=stream, min_interval_s=0.0)
        for done in range(1, 5):
            bar.update(done)
        bar.close()
    assert pipe.getvalue() == ""
    assert "\r" in terminal.getvalue() and "4/4" in terminal.getvalue()
    assert terminal.getvalue().endswith("\n")


def test_a_total_given_with_an_update_replaces_the_unknown_one():
    terminal = Terminal()
    bar = ProgressBar(0, "play", stream=terminal, min_interval_s=0.0)
    bar.update(1)
    assert "play 1 " in terminal.getvalue()  # no total yet: the count alone
    bar.update(2, 8)
    assert "2/8" in terminal.getvalue()


def test_leaving_the_bar_ends_its_line_even_when_the_work_fails():
    terminal = Terminal()
    try:
        with ProgressBar(3, "replay", stream=terminal, min_interval_s=0.0) as bar:
            bar.update(1)
            raise RuntimeError("the bag ended early")
    except RuntimeError:
        pass
    assert terminal.getvalue().endswith("\n")
