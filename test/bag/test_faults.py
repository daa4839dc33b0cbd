"""Fault injection into bags: cut short, bit-flipped, unfinished; replay keeps every good frame.

Each test damages a copy of one simulated flight at a chosen byte and checks
the output against an oracle taken from the intact bag: where each image's
CDR bytes lie in the MCAP file. A frame is good when its bytes are untouched
and lie before any cut; replay must write a result for every good frame, once,
and say what it skipped.
"""

from __future__ import annotations

import shutil

import pytest
from std_msgs.msg import String

from marker_localizer.bag.io import BagReader, BagWriter
from marker_localizer.bag.replay import replay_bag
from marker_localizer.cli import main as cli
from marker_localizer.cli.exits import EXIT_INCOMPLETE
from marker_localizer.errors import BagError

#: Bytes in front of a message's CDR in an MCAP file: record opcode and length
#: (9), channel, sequence, log and publish time (22).
MESSAGE_RECORD_HEAD = 9 + 22
#: Bytes in front of an Image's frame_id length in its CDR: encapsulation (4), stamp (8).
FRAME_ID_LENGTH_AT = 4 + 8


@pytest.fixture(scope="module")
def images(small_flight):
    """(camera, bag time) -> (start, end) byte span of the image's CDR in the MCAP file."""
    data = (small_flight / "flight_0.mcap").read_bytes()
    spans = {}
    with BagReader(small_flight) as bag:
        for message in bag.messages():
            if message.topic.endswith("/image_raw"):
                start = data.index(message.raw)
                camera = message.topic.strip("/").split("/")[0]
                spans[(camera, message.time_ns)] = (start, start + len(message.raw))
    assert len(spans) == 15
    return spans


def damaged_copy(flight, directory, change):
    """A copy of ``flight`` whose MCAP bytes went through ``change``."""
    copy = directory / "damaged"
    shutil.copytree(flight, copy)
    storage = copy / "flight_0.mcap"
    storage.write_bytes(change(storage.read_bytes()))
    return copy


def results(out):
    """(camera, bag time) of every marker cloud in a replay's output bag."""
    with BagReader(out) as bag:
        return [
            (message.topic.strip("/").split("/")[0], message.time_ns)
            for message in bag.messages()
            if message.topic.endswith("/marker_points")
        ]


def flip(data, at, bit):
    damaged = bytearray(data)
    damaged[at] ^= 1 << bit
    return bytes(damaged)


def test_a_bag_cut_short_gives_every_frame_before_the_cut_and_exit_status_3(
    small_flight, images, tmp_path, capsys
):
    cut = sorted(start for start, _ in images.values())[9] + 1000  # inside the 10th image
    bag = damaged_copy(small_flight, tmp_path, lambda data: data[:cut])
    out = tmp_path / "out"
    assert cli(["replay", str(bag), "--out", str(out), "--workers", "1"]) == EXIT_INCOMPLETE
    whole = {key for key, (_, end) in images.items() if end <= cut}
    assert len(whole) == 9
    written = results(out)
    assert sorted(written) == sorted(whole)  # each good frame once, nothing else
    summary = capsys.readouterr().out
    assert "cannot be opened through its index" in summary
    # What the cut took: what its metadata.yaml counted, less what can be read.
    with BagReader(small_flight) as intact, BagReader(bag) as damaged:
        lost = sum(intact.message_counts.values()) - sum(1 for _ in damaged.messages())
    assert lost > len(images) - len(whole)  # the frames' camera_info and truth too
    assert f": {lost} messages its metadata.yaml counts were not found (" in summary
    assert "incomplete: 0 image messages gave no result, the storage is damaged" in summary


def test_a_bag_cut_before_its_first_frame_is_one_line_naming_the_damage(
    small_flight, images, tmp_path, capsys
):
    """It said no frame could be processed, 0 of each kind skipped, and listed the encodings."""
    cut = min(start for start, _ in images.values()) - 1
    bag = damaged_copy(small_flight, tmp_path, lambda data: data[:cut])
    assert cli(["replay", str(bag), "--out", str(tmp_path / "out"), "--workers", "1"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "damaged: no frame to process: no message on /cam0/image_raw, /cam1/image_raw" in err
    assert "; damaged storage: " in err and "cannot be opened through its index" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["damaged"]


def test_a_flipped_bit_that_makes_a_frame_undecodable_costs_that_frame_only(
    small_flight, images, tmp_path
):
    victim = sorted(images)[6]
    start, _ = images[victim]
    high_byte = start + FRAME_ID_LENGTH_AT + 3  # of the frame_id length
    bag = damaged_copy(small_flight, tmp_path, lambda data: flip(data, high_byte, 6))
    report = replay_bag(bag, tmp_path / "out", workers=2)
    assert sorted(results(tmp_path / "out")) == sorted(set(images) - {victim})
    camera = report.cameras[victim[0]]
    assert camera.undecodable == 1
    assert "does not decode as sensor_msgs/msg/Image" in camera.last_error
    assert not report.complete and not report.damage


def test_a_flipped_bit_in_a_record_length_costs_that_message_only(small_flight, images, tmp_path):
    victim = sorted(images)[4]
    start, _ = images[victim]
    length_at = start - MESSAGE_RECORD_HEAD + 1
    bag = damaged_copy(small_flight, tmp_path, lambda data: flip(data, length_at + 4, 3))
    report = replay_bag(bag, tmp_path / "out", workers=2)
    assert sorted(results(tmp_path / "out")) == sorted(set(images) - {victim})
    assert any("found by index" in line for line in report.damage), report.damage
    assert any("1 indexed messages lost" in line for line in report.damage), report.damage


def test_a_recording_that_did_not_finish_is_read_front_to_back(small_flight, images, tmp_path):
    cut = sorted(end for _, end in images.values())[-3]  # right after the 13th image
    bag = damaged_copy(small_flight, tmp_path, lambda data: data[:cut])
    (bag / "metadata.yaml").unlink()
    report = replay_bag(bag, tmp_path / "out", workers=2)
    whole = {key for key, (_, end) in images.items() if end <= cut}
    assert sorted(results(tmp_path / "out")) == sorted(whole)
    assert report.damage[0].endswith(
        "no metadata.yaml (a recording that did not finish); its MCAP files read front to back"
    )


def test_an_unfinished_split_recordings_files_are_read_in_the_order_they_were_written(tmp_path):
    """rosbag2 numbers them NAME_0 ... NAME_11; read by name, NAME_10 came before NAME_2,
    and replay skipped the frames of NAME_2 ... NAME_9 as out of order."""
    recording = tmp_path / "flight"
    recording.mkdir()
    for k in range(12):
        with BagWriter(tmp_path / f"part{k}") as part:
            part.add_topic("/note", "std_msgs/msg/String")
            part.write("/note", (k + 1) * 10**9, String(data=str(k)))
        (tmp_path / f"part{k}" / f"part{k}_0.mcap").rename(recording / f"flight_{k}.mcap")
    with BagReader(recording) as bag:
        times = [message.time_ns for message in bag.messages()]
    assert times == [(k + 1) * 10**9 for k in range(12)]


def test_a_sqlite3_recording_without_its_metadata_is_read_from_its_storage_file(tmp_path):
    bag = tmp_path / "flight_db"
    argv = ["--out", str(bag), "--frames", "2", "--width", "64", "--height", "48"]
    assert cli(["simulate", *argv, "--storage", "sqlite3", "--cameras", "1"]) == 0
    (bag / "metadata.yaml").unlink()
    report = replay_bag(bag, tmp_path / "out", workers=1)
    assert sum(c.frames for c in report.cameras.values()) == 2
    assert report.damage == [
        f"{bag}: no metadata.yaml (a recording that did not finish); "
        "flight_db_0.db3 read on its own"
    ]


def test_a_cut_sqlite3_bag_is_one_error_naming_it(tmp_path, capsys):
    bag = tmp_path / "flight_db"
    argv = ["--out", str(bag), "--frames", "1", "--width", "64", "--height", "48"]
    assert cli(["simulate", *argv, "--storage", "sqlite3", "--cameras", "1"]) == 0
    storage = bag / "flight_db_0.db3"
    storage.write_bytes(storage.read_bytes()[: storage.stat().st_size // 2])
    with pytest.raises(BagError, match="flight_db: cannot open bag, corrupt or truncated"):
        replay_bag(bag, tmp_path / "out")
    assert cli(["replay", str(bag), "--out", str(tmp_path / "out")]) == 1
    assert capsys.readouterr().err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight_db"]
