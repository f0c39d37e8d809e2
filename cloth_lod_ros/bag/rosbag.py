"""rosbag2-compatible MCAP bags: write, read and recover (design §7).

A bag is a directory ``<name>/`` holding ``metadata.yaml`` and ``<name>_0.mcap``,
laid out as rosbag2 Jazzy's MCAP storage plugin writes it:

* profile ``ros2``; one ``ros2msg`` schema per message type whose data is the
  complete message definition (the type's ``.msg`` text, then every nested
  type once, each after a line of 80 ``=`` and a ``MSG: pkg/msg/Type`` line);
* one channel per topic, message encoding ``cdr``, with channel metadata
  ``offered_qos_profiles`` (the YAML list of QoS profiles) and
  ``topic_type_hash`` (the type's RIHS01 hash);
* a ``rosbag2`` metadata record holding the serialized ``metadata.yaml``
  (and ``ROS_DISTRO``), written at a clean close together with the summary and
  ``metadata.yaml`` itself (format version 9).

Message definitions and type hashes are read from the installed interface
packages (``<prefix>/share/<pkg>/msg/<Type>.msg`` and ``.json``), found through
``AMENT_PREFIX_PATH`` and the running interpreter's prefix.  This module needs
the ``mcap`` library only; it does not import rclpy.

Crash safety: messages are grouped in chunks that are written (and flushed to
the operating system) when they fill up or ``flush_interval`` seconds after
the chunk's first message, so a killed writer loses at most the chunk in
progress; :func:`recover` rebuilds a valid bag from the complete chunks.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import yaml

__all__ = ["BagError", "BagWriter", "BagReader", "BagMessage", "TopicInfo",
           "message_definition", "type_hash", "qos_profiles_yaml", "recover",
           "COMPRESSIONS"]

COMPRESSIONS = ("none", "zstd", "lz4")
_SEPARATOR = "=" * 80
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
               "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring"}
# rosbag2 writes "infinite" QoS durations as the largest rmw time.
_INFINITE = {"sec": 9223372036, "nsec": 854775807}


class BagError(RuntimeError):
    """A bag cannot be written or read; the message says which file and why."""


# -- message definitions ---------------------------------------------------------
def _interface_prefixes() -> list[Path]:
    prefixes = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(Path(sys.prefix))
    return list(dict.fromkeys(prefixes))


def _interface_file(type_name: str, suffix: str) -> Path:
    parts = type_name.split("/")
    if len(parts) != 3:
        raise BagError(f"{type_name!r} is not a full interface name like 'pkg/msg/Type'")
    package, kind, name = parts
    for prefix in _interface_prefixes():
        path = prefix / "share" / package / kind / f"{name}{suffix}"
        if path.is_file():
            return path
    raise BagError(f"no {name}{suffix} for {type_name} under share/{package}/{kind} in "
                   f"{[str(p) for p in _interface_prefixes()]}; is the package installed "
                   "and AMENT_PREFIX_PATH set?")


def _nested_types(package: str, text: str) -> list[str]:
    """Full names of the non-primitive field types of one ``.msg`` text, in order."""
    found = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        base = line.split()[0].split("[", 1)[0].split("<=", 1)[0]
        if base in _PRIMITIVES:
            continue
        full = base.replace("/", "/msg/", 1) if "/" in base else f"{package}/msg/{base}"
        found.append(full)
    return found


def message_definition(type_name: str) -> str:
    """The complete ``ros2msg`` definition of ``type_name`` as rosbag2 stores it.

    The top-level ``.msg`` text comes first; each nested type follows once
    (depth-first, in field order) after the two-line delimiter.
    """
    texts: dict[str, str] = {}

    def visit(name: str) -> None:
        if name in texts:
            return
        text = _interface_file(name, ".msg").read_text()
        texts[name] = text if text.endswith("\n") else text + "\n"
        for nested in _nested_types(name.split("/")[0], text):
            visit(nested)

    visit(type_name)
    top, *rest = texts
    return texts[top] + "".join(f"{_SEPARATOR}\nMSG: {name}\n{texts[name]}" for name in rest)


def type_hash(type_name: str) -> str:
    """The RIHS01 type description hash of ``type_name`` (from the installed ``.json``)."""
    data = json.loads(_interface_file(type_name, ".json").read_text())
    for entry in data.get("type_hashes", []):
        if entry.get("type_name") == type_name:
            return entry["hash_string"]
    raise BagError(f"no type hash for {type_name} in its .json")


def qos_profiles_yaml(reliability: str = "reliable", durability: str = "volatile",
                      depth: int = 10, history: str = "keep_last") -> list[dict]:
    """One offered QoS profile in rosbag2's version-9 form (a list of one dict)."""
    return [{"history": history, "depth": int(depth), "reliability": reliability,
             "durability": durability, "deadline": dict(_INFINITE),
             "lifespan": dict(_INFINITE), "liveliness": "automatic",
             "liveliness_lease_duration": dict(_INFINITE),
             "avoid_ros_namespace_conventions": False}]


# -- writing ----------------------------------------------------------------------
@dataclass
class TopicInfo:
    """A topic of a bag: ROS type, offered QoS (list of dicts), type hash, count."""

    name: str
    type_name: str
    qos: list = field(default_factory=list)
    type_hash: str = ""
    message_count: int = 0
    channel_id: int = 0


class BagWriter:
    """Writes one rosbag2 bag directory (thread-safe).

    Args:
        path: the bag directory; it must not exist yet, or be empty.
        compression: chunk compression, ``"none"``, ``"zstd"`` or ``"lz4"``.
        chunk_size: bytes of (uncompressed) messages per chunk.
        flush_interval: s; a chunk older than this is written at the next message,
            so a crash loses at most this much (or one chunk) of recording.
        custom_data: strings stored in ``metadata.yaml``'s ``custom_data``.

    Raises:
        BagError: the path exists and is not an empty directory, or cannot be
            created or written (the message names it and the reason).
    """

    def __init__(self, path: str | os.PathLike, compression: str = "zstd",
                 chunk_size: int = 1 << 20, flush_interval: float = 1.0,
                 custom_data: dict | None = None):
        from mcap.writer import CompressionType, Writer
        if compression not in COMPRESSIONS:
            raise BagError(f"compression must be one of {COMPRESSIONS}, got {compression!r}")
        self.path = Path(path)
        if self.path.exists() and not (self.path.is_dir() and not any(self.path.iterdir())):
            raise BagError(f"{self.path} already exists; a bag is never overwritten")
        self.mcap_path = self.path / f"{self.path.name}_0.mcap"
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._file = open(self.mcap_path, "wb")
        except OSError as exc:
            raise BagError(f"cannot create the bag {self.path}: {exc.strerror or exc}") from None
        self.compression = compression
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self.flush_interval = float(flush_interval)
        self.topics: dict[str, TopicInfo] = {}
        self._schemas: dict[str, int] = {}
        self._lock = threading.Lock()
        self.start_ns: int | None = None
        self.end_ns = 0
        self.message_count = 0
        self.closed = False
        self._chunk_opened: float | None = None
        self._writer = Writer(self._file, chunk_size=chunk_size, compression={
            "none": CompressionType.NONE, "zstd": CompressionType.ZSTD,
            "lz4": CompressionType.LZ4}[compression])
        self._guard(self._writer.start, "ros2", "cloth_lod_ros")

    def _guard(self, function, *args):
        try:
            return function(*args)
        except OSError as exc:
            self._abandon()
            raise BagError(f"writing {self.mcap_path} failed: {exc.strerror or exc}; "
                           "recording stopped (the complete chunks are recoverable)") from None

    def _abandon(self) -> None:
        self.closed = True
        try:
            self._file.close()
        except OSError:
            pass

    def add_topic(self, name: str, type_name: str, qos: list | None = None) -> TopicInfo:
        """Register a topic (idempotent for the same type); returns its info."""
        with self._lock:
            if name in self.topics:
                if self.topics[name].type_name != type_name:
                    raise BagError(f"topic {name} is already {self.topics[name].type_name}")
                return self.topics[name]
            if self.closed:
                raise BagError(f"bag {self.path} is closed")
            if type_name not in self._schemas:
                self._schemas[type_name] = self._guard(
                    self._writer.register_schema, type_name, "ros2msg",
                    message_definition(type_name).encode())
            info = TopicInfo(name, type_name, qos if qos is not None else qos_profiles_yaml(),
                             type_hash(type_name))
            info.channel_id = self._guard(
                self._writer.register_channel, name, "cdr", self._schemas[type_name],
                {"offered_qos_profiles": _yaml_dump(info.qos),
                 "topic_type_hash": info.type_hash})
            self.topics[name] = info
            return info

    def write(self, topic: str, data: bytes, time_ns: int) -> None:
        """Append one CDR message received/published at ``time_ns`` (ns since the epoch)."""
        with self._lock:
            if self.closed:
                raise BagError(f"bag {self.path} is closed")
            info = self.topics.get(topic)
            if info is None:
                raise BagError(f"topic {topic} was not added to the bag")
            self._guard(self._writer.add_message, info.channel_id, int(time_ns), bytes(data),
                        int(time_ns))
            info.message_count += 1
            self.message_count += 1
            self.start_ns = time_ns if self.start_ns is None else min(self.start_ns, time_ns)
            self.end_ns = max(self.end_ns, time_ns)
            now = _time.monotonic()
            if self._chunk_opened is None:
                self._chunk_opened = now
            elif now - self._chunk_opened >= self.flush_interval:
                self._flush_locked()

    def flush(self) -> None:
        """Write the chunk in progress and hand everything to the operating system."""
        with self._lock:
            if not self.closed:
                self._flush_locked()

    def _flush_locked(self) -> None:
        self._guard(self._writer.flush)
        self._chunk_opened = None

    def metadata(self) -> dict:
        """The ``rosbag2_bagfile_information`` mapping of ``metadata.yaml``."""
        start = self.start_ns or 0
        duration = max(self.end_ns - start, 0)
        return {
            "version": 9,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": self.message_count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.type_name,
                                    "serialization_format": "cdr",
                                    "offered_qos_profiles": t.qos,
                                    "type_description_hash": t.type_hash},
                 "message_count": t.message_count} for t in self.topics.values()],
            # rosbag2 compresses MCAP chunks inside the storage plugin: the bag
            # itself is not "compressed" in rosbag2's sense.
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.mcap_path.name],
            "files": [{"path": self.mcap_path.name,
                       "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration},
                       "message_count": self.message_count}],
            "custom_data": dict(self.custom_data),
            "ros_distro": "jazzy",
        }

    def close(self) -> None:
        """Finish the MCAP file (summary, indexes) and write ``metadata.yaml``."""
        with self._lock:
            if self.closed:
                return
            info = self.metadata()
            self._guard(self._writer.add_metadata, "rosbag2",
                        {"serialized_metadata": _yaml_dump(info), "ROS_DISTRO": "jazzy"})
            self._guard(self._writer.finish)
            self.closed = True
            try:
                self._file.close()
                _write_metadata(self.path, info)
            except OSError as exc:
                raise BagError(f"closing {self.path} failed: {exc.strerror or exc}") from None

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _yaml_dump(data) -> str:
    return yaml.safe_dump(data, default_flow_style=False, sort_keys=False).strip()


def _write_metadata(path: Path, info: dict) -> None:
    tmp = path / "metadata.yaml.tmp"
    tmp.write_text(yaml.safe_dump({"rosbag2_bagfile_information": info},
                                  default_flow_style=False, sort_keys=False))
    tmp.replace(path / "metadata.yaml")


# -- reading ------------------------------------------------------------------------
@dataclass
class BagMessage:
    """One recorded message: topic, ROS type, log time (ns since the epoch), CDR bytes."""

    topic: str
    type_name: str
    time_ns: int
    data: bytes


def _mcap_file(path: Path) -> Path:
    if path.is_file():
        return path
    if not path.is_dir():
        raise BagError(f"{path}: no such bag (a bag directory or an .mcap file)")
    meta = path / "metadata.yaml"
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
            files = [path / f for f in info["relative_file_paths"]]
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            raise BagError(f"{meta}: not a rosbag2 metadata file ({exc})") from None
    else:
        files = sorted(path.glob("*.mcap"))
    if len(files) != 1 or not files[0].is_file():
        raise BagError(f"{path}: expected one .mcap file, found {[str(f) for f in files]}")
    return files[0]


class BagReader:
    """Reads a bag written by :class:`BagWriter` (or rosbag2): a directory or a bare .mcap.

    Raises:
        BagError: missing, truncated, unfinished (no summary: use
            :func:`recover`) or corrupt file.
    """

    def __init__(self, path: str | os.PathLike):
        from mcap.reader import make_reader
        self.path = Path(path)
        self.mcap_path = _mcap_file(self.path)
        try:
            self._file = open(self.mcap_path, "rb")
            reader = make_reader(self._file, validate_crcs=True)   # catch damaged chunks
            summary = reader.get_summary()
        except Exception as exc:  # noqa: BLE001 - any parse failure means a bad file
            raise BagError(f"{self.mcap_path}: not a readable MCAP file ({_describe(exc)}); "
                           "if the recording was interrupted, `cloth-lod recover` "
                           "rebuilds it from its complete chunks") from None
        if summary is None or summary.statistics is None:
            raise BagError(f"{self.mcap_path}: the file was not closed (no summary); "
                           "`cloth-lod recover` rebuilds it from its complete chunks")
        self._reader = reader
        schemas = summary.schemas
        self.topics: dict[str, TopicInfo] = {}
        counts = summary.statistics.channel_message_counts
        for channel in summary.channels.values():
            schema = schemas.get(channel.schema_id)
            qos = yaml.safe_load(channel.metadata.get("offered_qos_profiles", "")) or []
            self.topics[channel.topic] = TopicInfo(
                channel.topic, schema.name if schema else "", qos,
                channel.metadata.get("topic_type_hash", ""),
                counts.get(channel.id, 0), channel.id)
        self.definitions = {s.name: s.data.decode() for s in schemas.values()}
        self.start_ns = summary.statistics.message_start_time
        self.end_ns = summary.statistics.message_end_time
        self.message_count = summary.statistics.message_count
        self.metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}

    def messages(self, topics=None) -> Iterator[BagMessage]:
        """Messages in log-time order, optionally only from ``topics``."""
        count = 0
        try:
            for schema, channel, message in self._reader.iter_messages(
                    topics=list(topics) if topics is not None else None, log_time_order=True):
                count += 1
                yield BagMessage(channel.topic, schema.name if schema else "",
                                 message.log_time, message.data)
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001 - CRC, decompression, truncation
            raise BagError(f"{self.mcap_path}: corrupt data after {count} messages "
                           f"({_describe(exc)})") from None

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "BagReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _describe(exc: Exception) -> str:
    text = str(exc) or type(exc).__name__
    return text if len(text) < 200 else text[:200] + "..."


# -- recovery -----------------------------------------------------------------------
@dataclass
class RecoveryReport:
    """What :func:`recover` found: messages and chunks kept, and why reading stopped."""

    output: Path
    messages: int
    chunks: int
    topics: int
    stopped_because: str


def recover(source: str | os.PathLike, output: str | os.PathLike | None = None,
            compression: str = "zstd") -> RecoveryReport:
    """Rebuild a valid bag from an interrupted (or damaged) recording.

    Reads the MCAP file record by record (the summary may be missing), keeps
    every message of every complete, intact chunk, and writes them with their
    topics, types, QoS and hashes to a new bag.  Reading stops at the first
    incomplete or corrupt record.

    Args:
        source: the bag directory or its .mcap file.
        output: the new bag directory (default ``<source>_recovered``).

    Raises:
        BagError: nothing readable (not an MCAP file), or the output exists.
    """
    from mcap.records import Channel, Chunk, Message, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk
    source = Path(source)
    mcap_path = _mcap_file(source) if source.is_dir() else source
    if not mcap_path.is_file():
        raise BagError(f"{mcap_path}: no such file")
    base = source if source.is_dir() else source.with_suffix("")
    output = Path(output) if output is not None else base.with_name(base.name + "_recovered")
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    kept: list[tuple[int, int, bytes]] = []
    chunks = 0
    stopped = "end of file"
    with open(mcap_path, "rb") as f:
        try:
            # Chunks are taken whole so that a damaged chunk is dropped entirely
            # (its CRC is checked when it is broken up).
            for record in StreamReader(f, skip_magic=False, emit_chunks=True).records:
                if isinstance(record, Chunk):
                    inner = breakup_chunk(record, validate_crc=True)
                    chunks += 1
                    records = inner
                else:
                    records = [record]
                for r in records:
                    if isinstance(r, Schema):
                        schemas[r.id] = r
                    elif isinstance(r, Channel):
                        channels[r.id] = r
                    elif isinstance(r, Message):
                        kept.append((r.channel_id, r.log_time, r.data))
        except Exception as exc:  # noqa: BLE001 - the first bad record ends the scan
            if chunks == 0 and not kept and not schemas:
                raise BagError(f"{mcap_path}: nothing recoverable ({_describe(exc)})") from None
            stopped = _describe(exc)
    writer = BagWriter(output, compression=compression)
    try:
        for cid, channel in channels.items():
            schema = schemas.get(channel.schema_id)
            if schema is None:
                continue
            qos = yaml.safe_load(channel.metadata.get("offered_qos_profiles", "")) or None
            writer.add_topic(channel.topic, schema.name, qos)
        for cid, log_time, data in sorted(kept, key=lambda m: m[1]):
            channel = channels.get(cid)
            if channel is not None and channel.topic in writer.topics:
                writer.write(channel.topic, data, log_time)
    finally:
        writer.close()
    return RecoveryReport(output, writer.message_count, chunks, len(writer.topics), stopped)
