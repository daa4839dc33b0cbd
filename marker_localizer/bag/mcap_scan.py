"""Read MCAP files front to back without their summary: what a damaged recording still holds.

rosbags reads an MCAP file through the index in its summary section, at the
end of the file. A recording killed mid-write has no summary (rosbags refuses
the file: "File end magic is invalid"), and a record damaged inside a chunk
stops rosbags' reading at that chunk. This module walks the records in file
order instead, as ``mcap recover`` does: schemas and channels where they
appear, messages in top-level records and inside chunks (decompressed with
rosbags' own codecs). Where the records stop making sense, it notes where and
why, goes on after the damaged chunk when the chunk's own length is intact,
and stops at the end of the readable data. Every whole message before a cut is
returned, those of an uncompressed chunk cut short included.

Record layout (MCAP specification, little-endian): opcode (1 byte), length
(8 bytes), body; strings are a 4-byte length and UTF-8 bytes.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from rosbags.rosbag2.storage_mcap import decompress

MAGIC = b"\x89MCAP0\r\n"
_FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX, _DATA_END = (
    0x02,
    0x03,
    0x04,
    0x05,
    0x06,
    0x07,
    0x0F,
)
#: Opcode and length in front of every record, bytes.
_RECORD_HEAD = 9
#: Channel id, sequence, log time and publish time in front of a message's data, bytes.
_MESSAGE_HEAD = 22

#: (topic, ROS type name, log time ns, CDR bytes) of one message.
Message = tuple[str, str, int, bytes]


class _DamageError(Exception):
    """A record is cut short or inconsistent."""


#: What reading a damaged record raises: ours, and what the bytes themselves cause.
_DAMAGE = (_DamageError, struct.error, ValueError, OverflowError)


@dataclass
class _Chunk:
    """A chunk's records (in the file, or decompressed) and the offsets of those read."""

    label: str
    stream: BinaryIO
    start: int
    end: int
    read: set[int] = field(default_factory=set)
    damaged: bool = False
    found_by_index: int = 0
    lost: int = 0

    def note(self, damage: list[str]) -> None:
        """Say what the message index added to this chunk's reading, if anything."""
        if self.found_by_index:
            after = "after the damage" if self.damaged else "its reading missed"
            damage.append(f"{self.label}: {self.found_by_index} messages {after} found by index")
        if self.lost:
            damage.append(f"{self.label}: {self.lost} indexed messages lost")


@dataclass
class ScanState:
    """What a scan learnt: channels (id -> topic, ROS type) and where it found damage."""

    channels: dict[int, tuple[str, str]] = field(default_factory=dict)
    schemas: dict[int, str] = field(default_factory=dict)
    damage: list[str] = field(default_factory=list)
    #: The chunk read last: the message index records that follow it locate the
    #: messages after a damaged record inside it.
    last_chunk: _Chunk | None = field(default=None, repr=False)


def scan_messages(path: Path, state: ScanState, *, with_data: bool = True) -> Iterator[Message]:
    """Every readable message of one MCAP file, in file order.

    Args:
        path: the ``.mcap`` file.
        state: collects the channels and the damage found (one line each).
        with_data: read the messages' bytes (False: count only, data is b"").

    Yields:
        (topic, ROS type name, log time ns, CDR bytes) per message.
    """
    with path.open("rb") as stream:
        if stream.read(len(MAGIC)) != MAGIC:
            state.damage.append(f"{path.name}: not an MCAP file (no magic)")
            return
        end = path.stat().st_size
        yield from _records(stream, len(MAGIC), end, path.name, state, with_data, None)
        if state.last_chunk is not None:
            state.last_chunk.note(state.damage)


def _records(
    stream: BinaryIO,
    start: int,
    end: int,
    where: str,
    state: ScanState,
    with_data: bool,
    chunk: _Chunk | None,
) -> Iterator[Message]:
    """The messages of the records between ``start`` and ``end`` (inside ``chunk``, if given)."""
    at = start
    while at < end:
        try:
            stream.seek(at)
            head = _read(stream, _RECORD_HEAD, at + _RECORD_HEAD <= end)
            opcode, length = head[0], struct.unpack_from("<Q", head, 1)[0]
            stop = at + _RECORD_HEAD + length
            if opcode in (_DATA_END, _FOOTER):
                return
            if opcode == _CHUNK:
                yield from _chunk(stream, at, min(stop, end), where, state, with_data)
                if stop > end:
                    state.damage.append(
                        f"{where}: ends {end - at} bytes into the {length}-byte chunk at byte {at}"
                    )
                    return
            elif stop > end:
                raise _DamageError(f"a record of {length} bytes ends beyond byte {end}")
            elif opcode == _MESSAGE:
                message = _message(stream, length, state, with_data)
                if chunk is not None:
                    chunk.read.add(at - chunk.start)
                if message is not None:
                    yield message
            elif opcode in (_SCHEMA, _CHANNEL):
                _definition(opcode, stream.read(length), state)
            elif opcode == _MESSAGE_INDEX and chunk is None and state.last_chunk is not None:
                yield from _indexed(stream.read(length), state.last_chunk, state, with_data)
        except _DAMAGE as err:
            state.damage.append(f"{where}: unreadable from byte {at} ({err})")
            if chunk is not None:
                chunk.damaged = True
            return
        at = stop


def _read(stream: BinaryIO, size: int, inside: bool = True) -> bytes:
    data = stream.read(size)
    if len(data) != size or not inside:
        raise _DamageError(f"{len(data)} of {size} bytes left")
    return data


def _string(stream: BinaryIO) -> str:
    (length,) = struct.unpack("<I", _read(stream, 4))
    return _read(stream, length).decode()


def _message(stream: BinaryIO, length: int, state: ScanState, with_data: bool) -> Message | None:
    if length < _MESSAGE_HEAD:
        raise _DamageError(f"a message record of {length} bytes")
    channel, _, log_time, _ = struct.unpack("<HIQQ", _read(stream, _MESSAGE_HEAD))
    if channel not in state.channels:
        return None  # a channel whose definition was lost: nothing to decode it as
    topic, msgtype = state.channels[channel]
    data = _read(stream, length - _MESSAGE_HEAD) if with_data else b""
    return topic, msgtype, log_time, data


def _definition(opcode: int, body: bytes, state: ScanState) -> None:
    record = io.BytesIO(body)
    (ident,) = struct.unpack("<H", _read(record, 2))
    if opcode == _SCHEMA:
        state.schemas[ident] = _string(record)
        return
    (schema,) = struct.unpack("<H", _read(record, 2))
    topic = _string(record)
    state.channels[ident] = (topic, state.schemas.get(schema, ""))


def _chunk(
    stream: BinaryIO, at: int, end: int, where: str, state: ScanState, with_data: bool
) -> Iterator[Message]:
    """The messages of the chunk record at ``at``, up to the damage or the cut, if any.

    Damage inside is noted, and reading goes on after the chunk (its own length
    says where the next record starts); the message index records after it
    then give the messages that reading missed (:func:`_indexed`).
    """
    label = f"{where}: chunk at byte {at}"
    if state.last_chunk is not None:
        state.last_chunk.note(state.damage)
    state.last_chunk = None
    try:
        stream.seek(at + _RECORD_HEAD)
        _, _, uncompressed_size, crc = struct.unpack("<QQQI", _read(stream, 28))
        compression = _string(stream)
        (records_length,) = struct.unpack("<Q", _read(stream, 8))
        start = stream.tell()
        if compression:
            compressed = _read(stream, records_length, start + records_length <= end)
            raw = decompress(compressed, compression, uncompressed_size, crc)
            chunk = _Chunk(label, io.BytesIO(raw), 0, len(raw))
        else:
            chunk = _Chunk(label, stream, start, min(start + records_length, end))
    except Exception as err:  # struct, ours, and rosbags' zstd / lz4 / size errors alike
        state.damage.append(f"{label} skipped ({err})")
        return
    state.last_chunk = chunk
    yield from _records(chunk.stream, chunk.start, chunk.end, label, state, with_data, chunk)


def _indexed(body: bytes, chunk: _Chunk, state: ScanState, with_data: bool) -> Iterator[Message]:
    """The messages of ``chunk`` that one of its message index records lists and reading missed.

    Reading a chunk record by record loses its place at a damaged record
    length; the index gives each message's offset, so only the damaged one is lost.
    """
    record = io.BytesIO(body)
    _, pairs_length = struct.unpack("<HI", _read(record, 6))
    offsets = {offset for _, offset in struct.iter_unpack("<QQ", _read(record, pairs_length))}
    for offset in sorted(offsets - chunk.read):
        chunk.read.add(offset)
        at = chunk.start + offset
        try:
            chunk.stream.seek(at)
            head = _read(chunk.stream, _RECORD_HEAD, at + _RECORD_HEAD <= chunk.end)
            length = struct.unpack_from("<Q", head, 1)[0]
            if head[0] != _MESSAGE or at + _RECORD_HEAD + length > chunk.end:
                raise _DamageError("not a whole message record")
            message = _message(chunk.stream, length, state, with_data)
        except _DAMAGE:
            chunk.lost += 1
            continue
        if message is not None:
            chunk.found_by_index += 1
            yield message
