"""Specification of ``bench bound``: the centre's bound with the rest of the marker unknown."""

from __future__ import annotations

import math

import pytest

from marker_localizer.bench import bound
from marker_localizer.synthetic.crlb import X_SNR_BANDS, BoundParts


def test_each_family_gets_a_row_per_bound_with_the_detectors_error_over_it():
    lines: list[str] = []
    figures = bound.run(["a"], [100], lines.append)
    family = figures["families"]["a"]
    assert family["found"] > 0
    rows = family["bounds"]
    assert list(rows) == list(BoundParts._fields)
    # The bound grows as less is known and fewer pixels are read, and the error over
    # each falls with it.
    means = [rows[field]["mean_px"] for field in ("known", "affine", "projective")]
    assert means == sorted(means)
    assert rows["inner_projective"]["mean_px"] > rows["projective"]["mean_px"]
    assert rows["known"]["error_over_bound"] == pytest.approx(
        family["mean_error_px"] / rows["known"]["mean_px"]
    )
    assert all(math.isfinite(row["error_over_bound"]) for row in rows.values())
    table = "\n".join(lines)
    assert all(label in table for label in bound.BOUND_LABELS.values())


def test_every_marker_is_counted_once_in_the_bands_of_its_xs_signal_to_noise_ratio():
    lines: list[str] = []
    family = bound.run(["b"], [100], lines.append)["families"]["b"]
    bands = family["by_x_snr"]
    assert [band["from"] for band in bands] == [0.0, *X_SNR_BANDS]
    assert [band["to"] for band in bands] == [*X_SNR_BANDS, None]
    assert sum(band["markers"] for band in bands) == family["markers"]
    assert sum(band["found"] for band in bands) == family["found"]
    assert all(0 <= band["found"] <= band["markers"] for band in bands)
    assert bound.SNR_HEADING in "\n".join(lines)


def test_an_unknown_family_is_refused_on_the_command_line(capsys: pytest.CaptureFixture[str]):
    with pytest.raises(SystemExit) as exit_info:
        bound.main(["--families", "a,x"])
    assert exit_info.value.code == 2
    assert "argument --families: unknown families ['x']" in capsys.readouterr().err
