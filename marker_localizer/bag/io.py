"""Bag reading and writing shared by ``simulate``, ``replay`` and ``play``.

rosbag2 itself is not installable here (no wheel), so bags go through
``rosbags`` (pure Python; MCAP and sqlite3 storage) for the container and
through ``rclpy.serialization`` for the messages: the bytes in a bag are the
CDR that ROS 2 puts on the wire, and ``deserialize_message`` turns them into the
same ``sensor_msgs.msg`` objects the node receives, so replay and the node share
one conversion path. Message definitions and type hashes written into a bag
come from rosbags' ROS 2 Jazzy typestore.

ROS 1 bags (``.bag``, read by rosbags too) are read as well: each message is
converted from ROS 1 serialisation to the CDR of the Jazzy type of the same name
(the header loses its ``seq``), so everything downstream sees ROS 2 messages.

Every failure a user can cause (a missing path, a file that is not a bag, a
corrupt or truncated bag, an output that exists) becomes a
:class:`~marker_localizer.errors.BagError` whose message names the path. A
:class:`BagWriter` writes into a hidden sibling directory and renames it onto
the requested path only when the bag was closed cleanly, so an interrupted
command never leaves a bag that looks complete. What it writes is laid out as
``ros2 bag record -o NAME`` lays it out: ``NAME/NAME_0.mcap`` (or ``.db3``) and
``NAME/metadata.yaml``, both naming ROS 2 Jazzy as their ``ros_distro``.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import logging
import os
import re
import shutil
import socket
import sqlite3
from collections import Counter
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, Self

import yaml
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import Qos
from rosbags.rosbag1 import Reader as Ros1Reader
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from marker_localizer.bag.mcap_scan import ScanState, scan_messages
from marker_localizer.errors import BagError, shorten

_LOG = logging.getLogger(__name__)
#: Storage formats a bag can be written in; MCAP is rosbag2's default since Iron.
STORAGES: dict[str, StoragePlugin] = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
DEFAULT_STORAGE = "mcap"
#: rosbag2 metadata version written (Jazzy's).
_BAG_VERSION: Literal[9] = 9
#: The typestore whose message definitions and type hashes the bags hold.
_TYPESTORE = Stores.ROS2_JAZZY
#: The ``ros_distro`` of the bags' metadata.yaml: the distro of that typestore,
#: which is what rosbag2 writes there (the distro it was built for).
ROS_DISTRO = _TYPESTORE.value.removeprefix("ros2_")
#: Suffixes of bag files, not of bag directories: an output named with one is
#: a file name given where rosbag2 makes a directory (``x.mcap/x.mcap.mcap``).
BAG_FILE_SUFFIXES = (".mcap", ".db3", ".bag")
#: First bytes of a ROS 1 bag (format 2.0, the only one rosbags and ROS 1 since 2010 write).
_ROS1_MAGIC = b"#ROSBAG V2.0\n"
#: Suffix of the storage file's name: rosbag2 numbers a bag's files from 0
#: (``NAME/NAME_0.mcap``), and ``ros2 bag reindex`` finds them by that number.
_FIRST_FILE_SUFFIX = "_0"


@functools.cache
def typestore() -> Typestore:
    """The ROS 2 Jazzy typestore of rosbags (message definitions and hashes; cached)."""
    return get_typestore(_TYPESTORE)


@functools.cache
def message_class(msgtype: str) -> type | None:
    """The rclpy message class of a ROS type name such as ``"sensor_msgs/msg/Image"``.

    Returns:
        The class, or None when its package is not installed (tf2_msgs, for one,
        has no wheel here).
    """
    package, _, name = msgtype.rpartition("/")
    try:
        return getattr(importlib.import_module(package.replace("/", ".")), name)
    except (ImportError, AttributeError, ValueError):
        return None


def missing_message_reason(msgtype: str) -> str:
    """Why :func:`message_class` finds no class for ``msgtype``, in a few words.

    A ROS 1 bag names types ROS 2 Jazzy lacks in packages it has (``/rosout``'s
    ``rosgraph_msgs/msg/Log``, which ROS 2 moved to ``rcl_interfaces``): saying
    "not installed" there would send the user to install what is installed.
    """
    package = msgtype.partition("/")[0]
    try:
        importlib.import_module(package)
    except (ImportError, ValueError):
        return f"package {package} not installed"
    return f"no such type in ROS 2 Jazzy's {package}"


def missing_messages_text(skipped: dict[str, str]) -> str:
    """Topic -> type of the topics without a message class, each with its reason."""
    return ", ".join(
        f"{topic} ({msgtype}: {missing_message_reason(msgtype)})"
        for topic, msgtype in sorted(skipped.items())
    )


def _recording_order(path: Path) -> tuple[int, str]:
    """Where a split recording's file ``NAME_N`` comes: by N, which its name alone misorders.

    rosbag2 numbers the files from 0; by name ``NAME_10`` would come before ``NAME_2``.
    """
    split = re.search(r"_(\d+)$", path.stem)
    return (int(split[1]) if split else -1, path.name)


@dataclass(frozen=True)
class BagMessage:
    """One serialised message of a bag.

    Attributes:
        topic: Topic name.
        msgtype: ROS type name, e.g. ``"sensor_msgs/msg/Image"``.
        time_ns: Bag (receive) time, ns since the epoch.
        raw: CDR bytes as on the wire.
    """

    topic: str
    msgtype: str
    time_ns: int
    raw: bytes

    def decode(self) -> Any:
        """Deserialise into the rclpy message object.

        Raises:
            BagError: the type's package is not installed or the bytes do not
                decode as that type.
        """
        cls = message_class(self.msgtype)
        if cls is None:
            raise BagError(f"{self.topic}: message package of {self.msgtype} is not installed")
        try:
            return deserialize_message(self.raw, cls)
        except Exception as err:  # rclpy raises several types for malformed CDR
            raise BagError(
                f"{self.topic}: message at {self.time_ns} ns does not decode as "
                f"{self.msgtype} ({err})"
            ) from err


def is_ros1_bag(path: Path) -> bool:
    """Whether ``path`` is a ROS 1 bag file (by its first bytes, not its name)."""
    try:
        with path.open("rb") as file:
            return file.read(len(_ROS1_MAGIC)) == _ROS1_MAGIC
    except OSError:  # a directory, or unreadable: not a ROS 1 bag
        return False


class BagReader:
    """Read a rosbag2 (a bag directory, or a bare ``.mcap`` / ``.db3`` file) or a ROS 1 ``.bag``.

    Use as a context manager. Damage is read around, not given up on: an MCAP
    storage that rosbags cannot open through its index (a recording cut short
    has none) or that fails part-way is read front to back
    (:mod:`marker_localizer.bag.mcap_scan`), so every whole message is still
    returned; so is a bag directory without ``metadata.yaml`` that holds MCAP
    files (a recording that did not finish), or one sqlite3 file, read on its own
    as a bare ``.db3`` is. What could not be read is listed
    in :attr:`damage`, one line each. Every other rosbags or storage error is a
    :class:`BagError` naming the path.

    Args:
        path: The bag.

    Raises:
        BagError: the path does not exist or is not a bag it can open.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        #: What could not be read, one line each (empty for an intact bag).
        self.damage: list[str] = []
        self._reader: Reader | None = None
        self._open = False
        # MCAP files read front to back instead of through rosbags' index.
        self._scanned_files: list[Path] = []
        self._scanned_topics: dict[str, str] = {}
        self._scanned_counts: dict[str, int] = {}
        self._ros1: Ros1Reader | None = None
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag")
        if self.path.is_file() and is_ros1_bag(self.path):
            self._ros1 = Ros1Reader(self.path)
            return
        storage = self.path
        if self.path.is_dir() and not (self.path / "metadata.yaml").exists():
            unfinished = f"{self.path}: no metadata.yaml (a recording that did not finish)"
            self._scanned_files = self._mcap_files()
            if self._scanned_files:
                self.damage.append(f"{unfinished}; its MCAP files read front to back")
                return
            sqlite = sorted(self.path.glob("*.db3"))
            if len(sqlite) != 1:
                raise BagError(
                    f"{self.path}: not a rosbag2 directory (no metadata.yaml; "
                    "an unfinished recording?)"
                )
            # A bare .db3 is a bag of its own (rosbags reads its schema from it).
            self.damage.append(f"{unfinished}; {sqlite[0].name} read on its own")
            storage = sqlite[0]
        try:
            self._reader = Reader(storage)
        except Exception as err:  # rosbags raises ReaderError or OSError
            raise BagError(f"{self.path}: not a rosbag2 ({err})") from err

    def __enter__(self) -> Self:
        if self._ros1 is not None:
            try:
                self._ros1.open()
            except Exception as err:  # rosbags' ReaderError, or OSError
                raise BagError(f"{self.path}: cannot open ROS 1 bag ({err})") from err
            self._open = True
            return self
        if self._reader is not None:
            try:
                self._reader.open()
                self._open = True
            except Exception as err:  # corrupt metadata, storage or index: any rosbags error
                if not self._mcap_files():
                    raise BagError(
                        f"{self.path}: cannot open bag, corrupt or truncated ({err})"
                    ) from err
                self.damage.append(
                    f"{self.path}: cannot be opened through its index ({shorten(str(err))}); "
                    "read front to back"
                )
                self._scanned_files = self._mcap_files()
        if self._scanned_files:
            self._index_by_scanning()
            if self._reader is not None:
                # A recording cut short keeps the metadata of what it had written:
                # what the scan did not find of that is lost.
                expected = Counter(_metadata_counts(self.path))
                expected.subtract(self._scanned_counts)
                self._note_missing(expected, "its metadata.yaml counts")
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if self._open and self._ros1 is not None:
            self._open = False
            self._ros1.close()
        if self._open and self._reader is not None:
            self._open = False
            self._reader.close()

    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> ROS type name, for every topic of the bag."""
        if self._scanned_files:
            return dict(self._scanned_topics)
        return {c.topic: c.msgtype for c in self._indexed().connections}

    @property
    def message_counts(self) -> dict[str, int]:
        """Topic name -> number of messages, from the bag's metadata (or the scan)."""
        if self._scanned_files:
            return dict(self._scanned_counts)
        counts: dict[str, int] = {}
        for connection in self._indexed().connections:
            counts[connection.topic] = counts.get(connection.topic, 0) + connection.msgcount
        return counts

    def messages(self, topics: Collection[str] | None = None) -> Iterator[BagMessage]:
        """Messages in bag-time order (file order where read front to back).

        Args:
            topics: Topic names to read; None reads all.

        Yields:
            :class:`BagMessage` per message. Where the storage fails part-way,
            an MCAP storage goes on front to back after the last message read,
            another ends there; either way :attr:`damage` says so.
        """
        if self._scanned_files:
            yield from self._scan(topics)
            return
        if self._ros1 is not None:
            yield from self._ros1_messages(topics)
            return
        reader = self._indexed()
        connections = [c for c in reader.connections if topics is None or c.topic in topics]
        if not connections:
            return
        stream = reader.messages(connections)
        # rosbags yields in time order: where it fails, every message older than the
        # last one it gave was given, and of those as old, the topics noted here.
        last_ns, topics_at_last = -1, set[str]()
        unread = Counter[str]()
        for connection in connections:
            unread[connection.topic] += connection.msgcount
        while True:
            try:
                connection, time_ns, raw = next(stream)
            except StopIteration:
                # A damaged record length inside a chunk can make rosbags skip the
                # rest of the chunk without an error: the counts tell.
                self._note_missing(unread, "its index counts")
                return
            except Exception as err:  # rosbags, zstd, sqlite and struct errors alike
                note = (
                    f"{self.path}: storage unreadable after the message at {last_ns} ns "
                    f"({type(err).__name__}: {shorten(str(err))})"
                )
                if not self._mcap_files():
                    self.damage.append(f"{note}; the rest cannot be read")
                    return
                self.damage.append(f"{note}; the rest read front to back")
                yield from self._scan(topics, after=(last_ns, topics_at_last))
                return
            if time_ns != last_ns:
                last_ns, topics_at_last = time_ns, set()
            topics_at_last.add(connection.topic)
            unread[connection.topic] -= 1
            yield BagMessage(connection.topic, connection.msgtype, time_ns, bytes(raw))

    def _note_missing(self, unread: Counter[str], counted_by: str) -> None:
        """A line of :attr:`damage` for the messages ``unread`` still holds, by topic."""
        missing = {topic: n for topic, n in unread.items() if n > 0}
        if missing:
            listed = ", ".join(f"{topic} {n}" for topic, n in missing.items())
            self.damage.append(
                f"{self.path}: {sum(missing.values())} messages {counted_by} "
                f"were not found ({shorten(listed)})"
            )

    def _indexed(self) -> Reader | Ros1Reader:
        reader = self._ros1 if self._ros1 is not None else self._reader
        if reader is None or not self._open:
            raise BagError(f"{self.path}: bag is not open (use BagReader as a context manager)")
        return reader

    def _ros1_messages(self, topics: Collection[str] | None) -> Iterator[BagMessage]:
        """A ROS 1 bag's messages, each converted to the CDR of its Jazzy type."""
        reader = self._indexed()
        connections = [c for c in reader.connections if topics is None or c.topic in topics]
        if not connections:
            return
        unconverted = Counter[str]()
        for connection, time_ns, raw in reader.messages(connections):
            try:
                cdr = typestore().ros1_to_cdr(raw, connection.msgtype)
            except Exception:  # a type Jazzy lacks, or bytes that do not fit it
                unconverted[connection.topic] += 1
                continue
            yield BagMessage(connection.topic, connection.msgtype, time_ns, bytes(cdr))
        for topic, count in unconverted.items():
            self.damage.append(
                f"{self.path}: {count} message(s) on {topic} ({reader.topics[topic].msgtype}) "
                "could not be converted from ROS 1 to a ROS 2 Jazzy type"
            )

    def _mcap_files(self) -> list[Path]:
        if self.path.is_dir():
            return sorted(self.path.glob("*.mcap"), key=_recording_order)
        return [self.path] if self.path.suffix == ".mcap" else []

    def _index_by_scanning(self) -> None:
        """Topics, counts and damage of the MCAP files, from one pass over their records."""
        for path in self._scanned_files:
            state = ScanState()
            for topic, *_ in scan_messages(path, state, with_data=False):
                self._scanned_counts[topic] = self._scanned_counts.get(topic, 0) + 1
            self._scanned_topics |= dict(state.channels.values())
            self.damage.extend(state.damage)

    def _scan(
        self, topics: Collection[str] | None, after: tuple[int, set[str]] | None = None
    ) -> Iterator[BagMessage]:
        """Messages of the MCAP files front to back, skipping those given before ``after``.

        Args:
            topics: Topic names to read; None reads all.
            after: (time, topics given at that time) of the last message read
                through the index before it failed; None: from the start (the
                damage was noted when the files were indexed).
        """
        files = self._scanned_files or self._mcap_files()
        for path in files:
            state = ScanState()
            for topic, msgtype, time_ns, raw in scan_messages(path, state):
                if topics is not None and topic not in topics:
                    continue
                if after is not None and (
                    time_ns < after[0] or (time_ns == after[0] and topic in after[1])
                ):
                    continue
                yield BagMessage(topic, msgtype, time_ns, raw)
            if after is not None:
                self.damage.extend(state.damage)


def _metadata_counts(path: Path) -> dict[str, int]:
    """Topic -> messages of a bag directory's ``metadata.yaml``; empty where it cannot tell."""
    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        return {
            entry["topic_metadata"]["name"]: int(entry["message_count"])
            for entry in info["topics_with_message_count"]
        }
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError):
        return {}


class BagWriter:
    """Write a new rosbag2, made visible at ``path`` only once it is complete.

    Use as a context manager. Messages go into ``.<name>.partial-<host>-<pid>/<name>``
    beside ``path``; a clean exit closes the bag (writing its index and
    ``metadata.yaml``) and renames it onto ``path``, an exception (an
    interruption included) removes it. A process killed outright (SIGKILL, a
    second signal, power loss) cannot remove it, so entering a writer first
    removes, beside ``path``, the staging directories of this host's processes
    that are gone. Storage errors (disk full, file too large, sqlite) are one
    :class:`BagError` naming the path. Write from the thread that entered it:
    the sqlite3 storage refuses any other.

    Args:
        path: The bag directory to create; must not exist, nor end in ``.mcap``,
            ``.db3`` or ``.bag`` (the names of bag files, not directories).
        storage: ``"mcap"`` or ``"sqlite3"``.

    Raises:
        BagError: ``path`` exists or is named as a bag file, its parent cannot
            be created, or ``storage`` is unknown.
    """

    def __init__(self, path: str | Path, storage: str = DEFAULT_STORAGE) -> None:
        self.path = Path(path)
        if storage not in STORAGES:
            raise BagError(f"unknown storage {storage!r}; choose from {', '.join(STORAGES)}")
        if self.path.suffix.lower() in BAG_FILE_SUFFIXES:
            raise BagError(
                f"{self.path}: names a bag directory, not a {self.path.suffix} file "
                f"(a rosbag2 is a directory of its storage file and metadata.yaml); "
                f"give it without {self.path.suffix}, e.g. {self.path.with_suffix('')}"
            )
        if self.path.exists() or self.path.is_symlink():
            raise BagError(f"{self.path}: output path exists; remove it or choose another")
        self.storage = storage
        self._staging = self.path.parent / _staging_name(self.path.name, os.getpid())
        # rosbags names the storage file after its directory: this one is renamed
        # onto ``path`` once complete, so the file is NAME_0.mcap, as rosbag2's.
        self._bag_dir = self._staging / f"{self.path.name}{_FIRST_FILE_SUFFIX}"
        self._writer: Writer | None = None
        self._connections: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    def __enter__(self) -> Self:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            sweep_staging(self.path.parent)
            if self._staging.exists():  # left by a killed run with the same pid
                shutil.rmtree(self._staging)
            self._staging.mkdir()
            self._writer = _Writer(
                self._bag_dir,
                version=_BAG_VERSION,
                storage_plugin=STORAGES[self.storage],
            )
            self._writer.open()
        except Exception as err:  # OSError or rosbags WriterError
            shutil.rmtree(self._staging, ignore_errors=True)
            raise BagError(
                f"{self.path}: cannot create bag ({_file_in_the_way(self.path) or err})"
            ) from err
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        writer, self._writer = self._writer, None
        if writer is None:
            return
        if exc_type is not None:
            with contextlib.suppress(Exception):  # a full disk fails the abort too; it goes anyway
                writer.abort()
            shutil.rmtree(self._staging, ignore_errors=True)
            return
        try:
            writer.close()
            _write_ros_distro(self._bag_dir / "metadata.yaml")
            self._bag_dir.rename(self.path)
        except Exception as err:
            raise BagError(f"{self.path}: cannot finish bag ({_storage_error(err)})") from err
        finally:
            shutil.rmtree(self._staging, ignore_errors=True)

    def set_metadata(self, key: str, value: str) -> None:
        """Store ``key: value`` in the bag's ``custom_data`` (metadata.yaml)."""
        self._open_writer().set_custom_data(key, value)

    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> None:
        """Declare a topic (once) before writing to it.

        Args:
            topic: Topic name.
            msgtype: ROS type name, e.g. ``"sensor_msgs/msg/PointCloud2"``.
            qos: Offered QoS profiles recorded for players (``ros2 bag play``
                uses them, e.g. transient-local for ``/tf_static``).
        """
        if topic in self._connections:
            return
        writer = self._open_writer()
        try:
            self._connections[topic] = writer.add_connection(
                topic,
                msgtype,
                typestore=typestore(),
                serialization_format="cdr",
                offered_qos_profiles=list(qos),
            )
        except (OSError, sqlite3.Error) as err:
            raise BagError(f"{self.path}: cannot write ({_storage_error(err)})") from err
        self.counts[topic] = 0

    def write(self, topic: str, time_ns: int, msg: Any) -> None:
        """Serialise an rclpy message and write it at bag time ``time_ns`` (ns)."""
        self.write_raw(topic, time_ns, serialize_message(msg))

    def write_raw(self, topic: str, time_ns: int, raw: bytes) -> None:
        """Write CDR bytes to a declared topic at bag time ``time_ns`` (ns).

        Raises:
            BagError: the topic was not declared with :meth:`add_topic`, or the
                storage failed (disk full, file too large, sqlite error).
        """
        if topic not in self._connections:
            raise BagError(f"{self.path}: topic {topic} was not declared")
        writer = self._open_writer()
        try:
            writer.write(self._connections[topic], time_ns, raw)
        except (OSError, sqlite3.Error) as err:
            raise BagError(f"{self.path}: cannot write ({_storage_error(err)})") from err
        self.counts[topic] += 1

    def _open_writer(self) -> Writer:
        if self._writer is None:
            raise BagError(f"{self.path}: bag is not open (use BagWriter as a context manager)")
        return self._writer


def _file_in_the_way(path: Path) -> str | None:
    """Which file stands where a folder above ``path`` is needed; None where none does.

    ``mkdir`` says "File exists" and names the file, not that it should be a folder.
    """
    blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    return None if blocking is None else f"{blocking} is a file, not a folder"


def _write_ros_distro(metadata: Path) -> None:
    """Set :data:`ROS_DISTRO` in a ``metadata.yaml`` rosbags wrote.

    rosbags writes ``ros_distro: rosbags`` and has no setting for it; the copy
    inside the storage file is set as it is written (:class:`_Writer`).
    """
    info = yaml.safe_load(metadata.read_text())
    info["rosbag2_bagfile_information"]["ros_distro"] = ROS_DISTRO
    metadata.write_text(yaml.safe_dump(info, default_flow_style=False, sort_keys=False))


def _with_ros_distro(metadata: str) -> str:
    """The metadata YAML a storage embeds, with :data:`ROS_DISTRO` as its ``ros_distro``.

    Text that is not a mapping with a ``ros_distro`` is returned as it is.
    """
    info = yaml.safe_load(metadata)
    if not isinstance(info, dict) or "ros_distro" not in info:
        return metadata
    info["ros_distro"] = ROS_DISTRO
    return yaml.safe_dump(info, default_flow_style=False, sort_keys=False).strip()


def _storage_naming_distro(storage: type[Any]) -> type[Any]:
    """A subclass of a rosbags storage writer whose embedded metadata names :data:`ROS_DISTRO`.

    rosbags' Writer gives its storage the metadata to embed (the MCAP file's
    ``rosbag2`` metadata record, the sqlite3 file's ``metadata`` table) as YAML
    text in ``close(version, metadata)``, with ``ros_distro: rosbags`` in it:
    what rosbag2 reads of a bare ``.mcap`` or ``.db3`` (``ros2 bag info``) and
    what ``ros2 bag reindex`` copies into a new ``metadata.yaml``.
    """

    class Storage(storage):
        def close(self, version: int, metadata: str) -> None:
            super().close(version, _with_ros_distro(metadata))

    Storage.__name__ = Storage.__qualname__ = storage.__name__
    return Storage


class _Writer(Writer):
    """rosbags' rosbag2 Writer whose storages embed ROS 2 Jazzy, not ``rosbags``, as the distro."""

    STORAGE_PLUGINS = {  # noqa: RUF012 - a class attribute of rosbags' Writer, read only
        plugin: _storage_naming_distro(storage)
        for plugin, storage in Writer.STORAGE_PLUGINS.items()
    }


_STAGING = re.compile(r"^\.(?P<name>.+)\.partial-(?P<host>.+)-(?P<pid>\d+)$")


def _staging_name(name: str, pid: int) -> str:
    return f".{name}.partial-{socket.gethostname()}-{pid}"


def sweep_staging(directory: Path) -> list[Path]:
    """Remove the staging directories in ``directory`` of this host's processes that are gone.

    Returns:
        The directories removed (each also logged as a warning).
    """
    host = socket.gethostname()
    removed = []
    for entry in directory.iterdir():
        match = _STAGING.match(entry.name)
        if match is None or match["host"] != host or not entry.is_dir():
            continue
        if _process_alive(int(match["pid"])):
            continue
        shutil.rmtree(entry, ignore_errors=True)
        removed.append(entry)
        _LOG.warning("removed %s, left by process %s that is gone", entry, match["pid"])
    return removed


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _storage_error(err: BaseException) -> str:
    """One line for a storage error: the OS's words for an OSError, the text otherwise."""
    if isinstance(err, OSError) and err.strerror:
        return err.strerror
    cause = err.__cause__ or err.__context__
    if isinstance(cause, OSError) and cause.strerror:
        return cause.strerror
    return shorten(" ".join(str(err).split()))
