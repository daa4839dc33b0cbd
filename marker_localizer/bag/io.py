"""rosbag2 reading and writing shared by ``simulate``, ``replay`` and ``play``.

rosbag2 itself is not installable here (no wheel), so bags go through
``rosbags`` (pure Python; MCAP and sqlite3 storage) for the container and
through ``rclpy.serialization`` for the messages: the bytes in a bag are the
CDR that ROS 2 puts on the wire, and ``deserialize_message`` turns them into the
same ``sensor_msgs.msg`` objects the node receives, so replay and the node share
one conversion path. Message definitions and type hashes written into a bag
come from rosbags' ROS 2 Jazzy typestore.

Every failure a user can cause (a missing path, a file that is not a bag, a
corrupt or truncated bag, an output that exists) becomes a
:class:`~marker_localizer.errors.BagError` whose message names the path. A
:class:`BagWriter` writes into a hidden sibling directory and renames it onto
the requested path only when the bag was closed cleanly, so an interrupted
command never leaves a bag that looks complete.

This module also holds the small terminal helpers the bag commands share
(:class:`ProgressBar`, :func:`run_command`).
"""

from __future__ import annotations

import functools
import importlib
import math
import os
import shutil
import sys
import time
from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Literal, Self

from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import Qos
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from marker_localizer.errors import BagError, MarkerLocalizerError

#: Storage formats a bag can be written in; MCAP is rosbag2's default since Iron.
STORAGES: dict[str, StoragePlugin] = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
DEFAULT_STORAGE = "mcap"
#: rosbag2 metadata version written (Jazzy's).
_BAG_VERSION: Literal[9] = 9


@functools.cache
def typestore() -> Typestore:
    """The ROS 2 Jazzy typestore of rosbags (message definitions and hashes; cached)."""
    return get_typestore(Stores.ROS2_JAZZY)


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


class BagReader:
    """Read a rosbag2 (a bag directory, or a bare ``.mcap`` / ``.db3`` file).

    Use as a context manager; every rosbags or storage error is turned into a
    :class:`BagError` naming the path.

    Args:
        path: The bag.

    Raises:
        BagError: the path does not exist or is not a bag it can open.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag")
        if self.path.is_dir() and not (self.path / "metadata.yaml").exists():
            raise BagError(
                f"{self.path}: not a rosbag2 directory (no metadata.yaml; an unfinished recording?)"
            )
        try:
            self._reader = Reader(self.path)
        except Exception as err:  # rosbags raises ReaderError or OSError
            raise BagError(f"{self.path}: not a rosbag2 ({err})") from err
        self._open = False

    def __enter__(self) -> Self:
        try:
            self._reader.open()
        except Exception as err:  # corrupt metadata, storage or index: any rosbags error
            raise BagError(f"{self.path}: cannot open bag, corrupt or truncated ({err})") from err
        self._open = True
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if self._open:
            self._open = False
            self._reader.close()

    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> ROS type name, for every topic of the bag."""
        return {c.topic: c.msgtype for c in self._reader.connections}

    @property
    def message_counts(self) -> dict[str, int]:
        """Topic name -> number of messages, from the bag's metadata."""
        counts: dict[str, int] = {}
        for connection in self._reader.connections:
            counts[connection.topic] = counts.get(connection.topic, 0) + connection.msgcount
        return counts

    @property
    def time_range_ns(self) -> tuple[int, int]:
        """(first, last) message time, ns since the epoch."""
        return self._reader.start_time, self._reader.end_time

    def messages(self, topics: Collection[str] | None = None) -> Iterator[BagMessage]:
        """Messages in bag-time order, optionally of some topics only.

        Args:
            topics: Topic names to read; None reads all.

        Yields:
            :class:`BagMessage` per message.

        Raises:
            BagError: the storage is corrupt or truncated where it is read.
        """
        connections = [c for c in self._reader.connections if topics is None or c.topic in topics]
        if not connections:
            return
        stream = self._reader.messages(connections)
        while True:
            try:
                connection, time_ns, raw = next(stream)
            except StopIteration:
                return
            except Exception as err:  # rosbags, zstd, sqlite and struct errors alike
                raise BagError(
                    f"{self.path}: bag is corrupt or truncated ({type(err).__name__}: {err})"
                ) from err
            yield BagMessage(connection.topic, connection.msgtype, time_ns, bytes(raw))


class BagWriter:
    """Write a new rosbag2, made visible at ``path`` only once it is complete.

    Use as a context manager. Messages go into ``.<name>.partial-<pid>/<name>``
    beside ``path``; a clean exit closes the bag (writing its index and
    ``metadata.yaml``) and renames it onto ``path``, an exception removes it.
    Write from the thread that entered it: the sqlite3 storage refuses any other.

    Args:
        path: The bag directory to create; must not exist.
        storage: ``"mcap"`` or ``"sqlite3"``.

    Raises:
        BagError: ``path`` exists, its parent cannot be created, or ``storage``
            is unknown.
    """

    def __init__(self, path: str | Path, storage: str = DEFAULT_STORAGE) -> None:
        self.path = Path(path)
        if storage not in STORAGES:
            raise BagError(f"unknown storage {storage!r}; choose from {', '.join(STORAGES)}")
        if self.path.exists() or self.path.is_symlink():
            raise BagError(f"{self.path}: output path exists; remove it or choose another")
        self.storage = storage
        self._staging = self.path.parent / f".{self.path.name}.partial-{os.getpid()}"
        self._writer: Writer | None = None
        self._connections: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    def __enter__(self) -> Self:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if self._staging.exists():  # left by a killed run with the same pid
                shutil.rmtree(self._staging)
            self._staging.mkdir()
            self._writer = Writer(
                self._staging / self.path.name,
                version=_BAG_VERSION,
                storage_plugin=STORAGES[self.storage],
            )
            self._writer.open()
        except Exception as err:  # OSError or rosbags WriterError
            shutil.rmtree(self._staging, ignore_errors=True)
            raise BagError(f"{self.path}: cannot create bag ({err})") from err
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
            writer.abort()
            shutil.rmtree(self._staging, ignore_errors=True)
            return
        try:
            writer.close()
            (self._staging / self.path.name).rename(self.path)
        except Exception as err:
            raise BagError(f"{self.path}: cannot finish bag ({err})") from err
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
        self._connections[topic] = self._open_writer().add_connection(
            topic,
            msgtype,
            typestore=typestore(),
            serialization_format="cdr",
            offered_qos_profiles=list(qos),
        )
        self.counts[topic] = 0

    def write(self, topic: str, time_ns: int, msg: Any) -> None:
        """Serialise an rclpy message and write it at bag time ``time_ns`` (ns)."""
        self.write_raw(topic, time_ns, serialize_message(msg))

    def write_raw(self, topic: str, time_ns: int, raw: bytes) -> None:
        """Write CDR bytes to a declared topic at bag time ``time_ns`` (ns).

        Raises:
            BagError: the topic was not declared with :meth:`add_topic`.
        """
        if topic not in self._connections:
            raise BagError(f"{self.path}: topic {topic} was not declared")
        self._open_writer().write(self._connections[topic], time_ns, raw)
        self.counts[topic] += 1

    def _open_writer(self) -> Writer:
        if self._writer is None:
            raise BagError(f"{self.path}: bag is not open (use BagWriter as a context manager)")
        return self._writer


# --------------------------------------------------------------------------- terminal helpers


class ProgressBar:
    """A one-line progress bar on a terminal, silent when the stream is not a TTY.

    Args:
        total: Number of steps (0: unknown, only the count is shown).
        label: Text before the bar.
        stream: Where to draw (default: ``sys.stderr``).
        min_interval_s: Least time between two redraws, s.
    """

    _WIDTH = 30

    def __init__(
        self,
        total: int,
        label: str,
        stream: IO[str] | None = None,
        min_interval_s: float = 0.1,
    ) -> None:
        self.total = total
        self.label = label
        self._stream = stream if stream is not None else sys.stderr
        self._enabled = bool(getattr(self._stream, "isatty", lambda: False)())
        self._min_interval_s = min_interval_s
        self._start = time.monotonic()
        self._last_draw = -math.inf  # the first update always draws

    def update(self, done: int) -> None:
        """Show ``done`` steps completed."""
        now = time.monotonic()
        too_soon = now - self._last_draw < self._min_interval_s and done < self.total
        if not self._enabled or too_soon:
            return
        self._last_draw = now
        elapsed = now - self._start
        rate = done / elapsed if elapsed > 0 else 0.0
        if self.total > 0:
            filled = round(self._WIDTH * min(done / self.total, 1.0))
            bar = "#" * filled + "." * (self._WIDTH - filled)
            text = f"{self.label} [{bar}] {done}/{self.total} {rate:.1f}/s"
        else:
            text = f"{self.label} {done} {rate:.1f}/s"
        self._stream.write(f"\r{text}\x1b[K")
        self._stream.flush()

    def close(self) -> None:
        """End the bar's line."""
        if self._enabled:
            self._stream.write("\n")
            self._stream.flush()


def run_command(name: str, body: Callable[[], int]) -> int:
    """Run a command's body; a package error becomes one line on stderr and status 1.

    Args:
        name: Command name for the message (``"replay"``).
        body: The command; returns its exit status.

    Returns:
        ``body``'s status, 1 after a :class:`MarkerLocalizerError`, 130 after Ctrl-C.
    """
    try:
        return body()
    except MarkerLocalizerError as err:
        sys.stderr.write(f"marker-localizer {name}: error: {err}\n")
        return 1
    except KeyboardInterrupt:
        sys.stderr.write(f"marker-localizer {name}: interrupted\n")
        return 130
