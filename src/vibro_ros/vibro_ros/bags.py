"""rosbag2 directories with MCAP storage: write (chunked, crash-tolerant), read back, reindex.

A bag is ``<dir>/metadata.yaml`` + ``<dir>/<name>_0.mcap`` with ``cdr`` messages and
``ros2msg`` schemas (vibro_msgs definitions included), laid out as ROS 2 Jazzy's rosbag2
writes it (metadata version 9): fully qualified topic names (``/vibro/frames``,
``/lab1/vibro/frames`` under a namespace), the publishers' offered QoS profiles per topic
in metadata.yaml and in each MCAP channel's metadata (``offered_qos_profiles``,
``topic_type_hash``), and the bag's metadata as an MCAP metadata record ``rosbag2``
(``serialized_metadata``), so ``ros2 bag info``/``ros2 bag play`` treat it as their own.

The writer pushes every finished chunk to the OS, finishes the chunk in progress at least
once a second and rewrites metadata.yaml as it goes, so a killed recorder leaves a bag
readable up to its last complete chunk: :func:`read_messages` recovers such a bag with a
warning, and :func:`reindex` rewrites it with an index so rosbags and mcap open it too.
"""

from __future__ import annotations

import logging
import os
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import yaml
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from vibro_model.errors import RecordingError

from .qos_format import dump_profiles, parse_profiles

log = logging.getLogger(__name__)

ROS_DISTRO = "jazzy"
_SEPARATOR = "=" * 80


class BagError(RecordingError):
    """A bag that cannot be written or read."""


def vibro_msgs_dir() -> Path:
    """Folder of the vibro_msgs .msg files (installed share/ first, else the source tree)."""
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix and (Path(prefix) / "share" / "vibro_msgs" / "msg").is_dir():
            return Path(prefix) / "share" / "vibro_msgs" / "msg"
    here = Path(__file__).resolve().parents[2] / "vibro_msgs" / "msg"
    if here.is_dir():
        return here
    raise BagError("cannot find the vibro_msgs .msg files (build vibro_msgs, or set AMENT_PREFIX_PATH)")


def make_typestore():
    """A rosbags typestore with ROS 2 Jazzy's standard types and the vibro_msgs types."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for path in sorted(vibro_msgs_dir().glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(encoding="utf-8"), f"vibro_msgs/msg/{path.stem}"))
    store.register(types)
    return store


@dataclass
class _TopicInfo:
    name: str
    msg_type: str
    channel_id: int
    type_hash: str
    offered_qos: list = field(default_factory=list)  # rosbag2 version-9 profile mappings
    count: int = 0


class _FlushingFile:
    """File wrapper that pushes every write to the OS, so SIGKILL loses nothing written."""

    def __init__(self, path: Path):
        self._f = open(path, "wb", buffering=0)  # noqa: SIM115 - closed by BagWriter.close

    def write(self, data) -> int:
        return self._f.write(data)

    def tell(self) -> int:
        return self._f.tell()

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self._f.close()


#: MCAP chunk compressions. lz4 costs about 0.1 ms per 77 kB camera frame against 0.3 ms for
#: zstd (level 3, the mcap library's); noisy speckle images hardly compress with either.
CHUNK_COMPRESSIONS = {"lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD, "none": CompressionType.NONE}


class BagWriter:
    """Write a rosbag2 (MCAP storage) directory; messages are serialized CDR bytes."""

    def __init__(self, path: str | Path, *, chunk_size: int = 512 * 1024, metadata_every_s: float = 1.0,
                 custom_data: dict[str, str] | None = None, compression: str = "lz4",
                 flush_every_s: float = 1.0):
        self.path = Path(path)
        if compression not in CHUNK_COMPRESSIONS:
            raise BagError(f"chunk compression {compression!r}: must be one of {', '.join(CHUNK_COMPRESSIONS)}")
        if self.path.exists():
            raise BagError(f"{self.path}: already exists; choose a new bag name")
        self.path.mkdir(parents=True)
        self.file_name = f"{self.path.name}_0.mcap"
        self._file = _FlushingFile(self.path / self.file_name)
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CHUNK_COMPRESSIONS[compression])
        self._writer.start(profile="ros2", library="vibro")
        self._store = make_typestore()
        self._schemas: dict[str, int] = {}
        self.topics: dict[str, _TopicInfo] = {}
        self.t_min = 2**63 - 1
        self.t_max = 0
        self._metadata_every_s = metadata_every_s
        self._flush_every_s = flush_every_s
        self.custom_data = dict(custom_data or {})
        self._last_metadata = 0.0
        self._last_flush = time.monotonic()
        self._unflushed = 0
        self.write_metadata()

    def add_topic(self, topic: str, msg_type: str, qos_profiles: list | None = None) -> None:
        """Declare a topic of ROS type ``pkg/msg/Type`` (idempotent).

        ``topic`` as rosbag2 records it: fully qualified (``/vibro/frames``); ``qos_profiles``:
        the profiles its publishers offered, as :func:`vibro_ros.qos_format.profile_dict` makes them.
        """
        if topic in self.topics:
            return
        if msg_type not in self._store.types:
            raise BagError(f"{self.path}: message type {msg_type} is unknown to the bag writer")
        if msg_type not in self._schemas:
            text, _ = self._store.generate_msgdef(msg_type, ros_version=2)
            self._schemas[msg_type] = self._writer.register_schema(msg_type, "ros2msg", text.encode())
        qos = list(qos_profiles or [])
        type_hash = self._store.hash_rihs01(msg_type)
        channel = self._writer.register_channel(topic, "cdr", self._schemas[msg_type],
                                                {"offered_qos_profiles": dump_profiles(qos),
                                                 "topic_type_hash": type_hash})
        self.topics[topic] = _TopicInfo(topic, msg_type, channel, type_hash, qos)
        self.write_metadata()

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        info = self.topics.get(topic)
        if info is None:
            raise BagError(f"{self.path}: topic {topic} was not added before writing")
        self._writer.add_message(info.channel_id, log_time=timestamp_ns, data=bytes(data),
                                 publish_time=timestamp_ns, sequence=info.count)
        info.count += 1
        self._unflushed += 1
        self.t_min = min(self.t_min, timestamp_ns)
        self.t_max = max(self.t_max, timestamp_ns)
        self.flush_if_due()

    def flush_if_due(self) -> None:
        """Finish the chunk in progress once ``flush_every_s`` has passed, and rewrite metadata.yaml
        every ``metadata_every_s``: what a SIGKILL can lose is bounded in time, not only in bytes.
        Call it from a timer too, so a quiet topic's last messages reach the disk."""
        now = time.monotonic()
        if self._unflushed and now - self._last_flush > self._flush_every_s:
            self._writer.flush()
            self._unflushed = 0
            self._last_flush = now
        if now - self._last_metadata > self._metadata_every_s:
            self.write_metadata()

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    def _info(self) -> dict:
        return bag_information(self.file_name, list(self.topics.values()),
                               self.t_min if self.message_count else 0,
                               max(0, self.t_max - self.t_min) if self.message_count else 0, self.custom_data)

    def write_metadata(self) -> None:
        """(Re)write metadata.yaml for what has been written so far (atomic replace)."""
        self._last_metadata = time.monotonic()
        write_metadata_file(self.path, self._info())

    def close(self) -> None:
        """Write the ``rosbag2`` metadata record, the MCAP summary/index and the final metadata.yaml."""
        info = self._info()
        self._writer.add_metadata("rosbag2", {"serialized_metadata": serialized_metadata(info)})
        self._writer.finish()
        self._file.close()
        write_metadata_file(self.path, info)


def bag_information(file_name: str, topics: list, start_ns: int, duration_ns: int,
                    custom_data: dict[str, str] | None = None) -> dict:
    """The ``rosbag2_bagfile_information`` mapping (version 9) of a one-file MCAP bag.

    ``topics``: objects with ``name``, ``msg_type``, ``offered_qos``, ``type_hash``, ``count``.
    """
    count = sum(t.count for t in topics)
    return {
        "version": 9,
        "storage_identifier": "mcap",
        "relative_file_paths": [file_name],
        "duration": {"nanoseconds": int(duration_ns)},
        "starting_time": {"nanoseconds_since_epoch": int(start_ns)},
        "message_count": count,
        "topics_with_message_count": [
            {"topic_metadata": {"name": t.name, "type": t.msg_type, "serialization_format": "cdr",
                                "offered_qos_profiles": list(t.offered_qos), "type_description_hash": t.type_hash},
             "message_count": t.count}
            for t in topics
        ],
        "compression_format": "",
        "compression_mode": "",
        "files": [{"path": file_name, "starting_time": {"nanoseconds_since_epoch": int(start_ns)},
                   "duration": {"nanoseconds": int(duration_ns)}, "message_count": count}],
        "custom_data": custom_data or None,
        "ros_distro": ROS_DISTRO,
    }


#: libyaml's emitter when PyYAML has it: the recorder rewrites metadata.yaml every second, and the pure-Python
#: emitter took ~30 ms per rewrite of a 12 KB file (5x libyaml's)
_YAML_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def _dump_yaml(data: dict) -> str:
    return yaml.dump(data, Dumper=_YAML_DUMPER, sort_keys=False)


def serialized_metadata(info: dict) -> str:
    """The ``serialized_metadata`` of the MCAP ``rosbag2`` record: the information mapping as YAML."""
    return _dump_yaml(info)


def write_metadata_file(bag: Path, info: dict) -> None:
    """Write ``bag/metadata.yaml`` (atomic replace)."""
    tmp = bag / "metadata.yaml.tmp"
    tmp.write_text(_dump_yaml({"rosbag2_bagfile_information": info}), encoding="utf-8")
    tmp.replace(bag / "metadata.yaml")


def _bag_information(bag: str | Path) -> dict:
    path = Path(bag) / "metadata.yaml"
    if not path.is_file():
        raise BagError(f"{bag}: no metadata.yaml (not a rosbag2 directory)")
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
    except (yaml.YAMLError, KeyError, TypeError) as exc:
        raise BagError(f"{path}: not a rosbag2 metadata file ({exc})") from None


def read_custom_data(bag: str | Path) -> dict[str, str]:
    """The ``custom_data`` strings of a bag's metadata.yaml (empty when none)."""
    return dict(_bag_information(bag).get("custom_data") or {})


def recorded_topics(bag: str | Path) -> dict[str, str]:
    """{topic name as recorded: ROS type ``pkg/msg/Type``} from a bag's metadata.yaml."""
    try:
        return {t["topic_metadata"]["name"]: t["topic_metadata"]["type"]
                for t in _bag_information(bag).get("topics_with_message_count") or []}
    except (KeyError, TypeError) as exc:
        raise BagError(f"{bag}/metadata.yaml: malformed topic list ({exc})") from None


def recorded_message_counts(bag: str | Path) -> dict[str, int]:
    """{topic name as recorded: message count} from a bag's metadata.yaml: what the recorder wrote, which a
    truncated or damaged file may no longer hold whole (compare with what :func:`read_messages` yields)."""
    try:
        return {t["topic_metadata"]["name"]: int(t.get("message_count", 0))
                for t in _bag_information(bag).get("topics_with_message_count") or []}
    except (KeyError, TypeError, ValueError) as exc:
        raise BagError(f"{bag}/metadata.yaml: malformed topic list ({exc})") from None


@dataclass
class BagMessage:
    topic: str           # the name asked for (vibro's topic table) when read with a filter, else as recorded
    msg_type: str
    timestamp_ns: int
    data: bytes
    recorded_topic: str = ""  # the name as stored in the bag (rosbag2: fully qualified)
    schema: bytes = b""       # the ros2msg definition the bag embeds for msg_type (empty: unknown, use vibro's)


def _mcap_files(bag: Path) -> list[Path]:
    if bag.is_file() and bag.suffix == ".mcap":
        return [bag]
    if not bag.is_dir():
        raise BagError(f"{bag}: no such bag directory")
    files = sorted(bag.glob("*.mcap"))
    if not files:
        raise BagError(f"{bag}: no .mcap file (only rosbag2 bags with MCAP storage are read)")
    return files


def matching_name(recorded: str, wanted: set[str]) -> str | None:
    """Which of the ``wanted`` topic names (as vibro's topic table writes them) a recorded topic is.

    A relative name (``vibro/frames``) matches itself (bags written before names were fully
    qualified) and ``/vibro/frames`` or ``/<namespace>/vibro/frames`` (rosbag2's fully
    qualified names, any namespace); an absolute name (``/diagnostics``) only itself.
    """
    if recorded in wanted:
        return recorded
    if recorded.startswith("/"):
        for name in wanted:
            if not name.startswith("/") and recorded.endswith("/" + name):
                return name
    return None


def _records(path: Path, counter: list[int]) -> Iterator:
    """The records of one MCAP file in file order; stops with a warning where the file is cut or damaged.

    ``counter[0]`` counts the messages yielded (for the warning).
    """
    with open(path, "rb") as handle:
        reader = StreamReader(handle, skip_magic=False, emit_chunks=False)
        try:
            yield from reader.records
        except (McapError, EOFError, ValueError, KeyError, RuntimeError, struct.error) as exc:
            log.warning("%s: bag is truncated or damaged after %d messages (%s); the readable part is used",
                        path, counter[0], exc.__class__.__name__)


def read_messages(bag: str | Path, topics: set[str] | None = None) -> Iterator[BagMessage]:
    """Stream messages in file order, tolerating a truncated last chunk (warns what was lost).

    ``topics``: names as in vibro's topic table (:func:`matching_name`: a bag recorded by
    rosbag2 or under a namespace holds ``/ns/vibro/frames`` for ``vibro/frames``); each
    message's ``topic`` is then the name asked for. A bag holding one name under two
    namespaces is refused (which run?). Types read must be known (ROS 2 Jazzy standard or
    vibro_msgs): a topic of unknown type is refused with its type name when it is read,
    skipped when it is not.
    """
    bag = Path(bag)
    store = make_typestore()
    wanted = set(topics) if topics is not None else None
    chosen: dict[str, str] = {}  # wanted name -> recorded name
    for path in _mcap_files(bag):
        schemas: dict[int, Schema] = {}
        channels: dict[int, tuple[str, str]] = {}  # channel id -> (name to report, type)
        counter = [0]
        for record in _records(path, counter):
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                name = record.topic if wanted is None else matching_name(record.topic, wanted)
                if name is None:
                    continue
                if wanted is not None and chosen.setdefault(name, record.topic) != record.topic:
                    raise BagError(f"{bag}: {name} is recorded twice, as {chosen[name]} and {record.topic} "
                                   "(two namespaces); split the bag per namespace")
                schema = schemas.get(record.schema_id)
                if schema is None or schema.name not in store.types:
                    type_name = schema.name if schema else f"schema id {record.schema_id}"
                    raise BagError(f"{path}: topic {record.topic} has type {type_name}, which vibro does not "
                                   "know (not a vibro bag?)")
                if record.message_encoding != "cdr":
                    raise BagError(f"{path}: topic {record.topic} is encoded as "
                                   f"{record.message_encoding}, not cdr")
                channels[record.id] = (name, schema.name, schema.data if schema.encoding == "ros2msg" else b"")
            elif isinstance(record, Message):
                found = channels.get(record.channel_id)
                if found is not None:
                    counter[0] += 1
                    yield BagMessage(found[0], found[1], record.log_time, record.data,
                                     chosen.get(found[0], found[0]), found[2])


def deserialize(message: BagMessage, store=None):
    """Decode a message's CDR bytes into a rosbags dataclass of its type, by the definition the bag embeds when
    it differs from vibro's (a bag recorded before a message gained fields: the object then lacks them)."""
    store = store or make_typestore()
    if not message.schema or message.schema == _definition(store, message.msg_type):
        return store.deserialize_cdr(message.data, message.msg_type)
    from rosbags.typesys.base import TypesysError

    where = message.recorded_topic or message.topic
    try:
        return _recorded_typestore(message.msg_type, message.schema).deserialize_cdr(message.data, message.msg_type)
    except (TypesysError, UnicodeDecodeError, KeyError, IndexError, ValueError, struct.error) as exc:
        raise BagError(f"{where}: a {message.msg_type} message does not decode by the definition the bag embeds "
                       f"({exc.__class__.__name__}: {exc})") from None


_DEFINITIONS: dict[tuple[int, str], bytes] = {}
_RECORDED_STORES: dict[tuple[str, bytes], object] = {}


def _definition(store, msg_type: str) -> bytes:
    """The ros2msg text the bag writer embeds for ``msg_type`` (cached per typestore)."""
    key = (id(store), msg_type)
    if key not in _DEFINITIONS:
        _DEFINITIONS[key] = store.generate_msgdef(msg_type, ros_version=2)[0].encode()
    return _DEFINITIONS[key]


def _recorded_typestore(msg_type: str, schema: bytes):
    """A typestore with ROS 2 Jazzy's standard types and ``msg_type`` as a bag's embedded ros2msg text defines it
    (its dependencies from the text too; cached per definition)."""
    key = (msg_type, schema)
    if key not in _RECORDED_STORES:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        store = get_typestore(Stores.ROS2_JAZZY)
        types = get_types_from_msg(schema.decode("utf-8"), msg_type)  # TypesysError: not a definition
        store.register({k: v for k, v in types.items() if k not in store.types})
        _RECORDED_STORES[key] = store
    return _RECORDED_STORES[key]


@dataclass
class ReindexReport:
    bag: Path
    messages: int
    per_topic: dict[str, int]
    backups: list[Path]


def reindex(bag: str | Path, chunk_size: int = 512 * 1024, compression: str = "lz4",
            keep_backup: bool = True) -> ReindexReport:
    """Rewrite a bag's MCAP files with a summary and index and its metadata.yaml with the real counts.

    What ``ros2 bag reindex`` does for a bag whose recorder was killed, plus the MCAP index
    itself (rosbags and mcap's indexed reader need it): every message up to the last
    complete chunk is kept with its times, sequence number, channel and channel metadata
    (offered QoS); the ``rosbag2`` metadata record is written; custom_data (vibro's rig.yaml)
    is carried over. The cut original is kept as ``<file>.cut`` unless ``keep_backup`` is False.
    """
    bag = Path(bag)
    if not bag.is_dir():
        raise BagError(f"{bag}: no such bag directory")
    if compression not in CHUNK_COMPRESSIONS:
        raise BagError(f"chunk compression {compression!r}: must be one of {', '.join(CHUNK_COMPRESSIONS)}")
    custom: dict[str, str] = {}
    if (bag / "metadata.yaml").is_file():
        try:
            custom = read_custom_data(bag)
        except BagError as exc:
            log.warning("%s; custom_data is not carried over", exc)
    store = make_typestore()
    topics: dict[str, _TopicInfo] = {}
    files: list[dict] = []
    t_first, t_last = 2**63 - 1, 0
    paths = _mcap_files(bag)
    for path in paths:  # pass 1: what is readable, per topic
        n, first, last = _scan_mcap(path, topics, store)
        files.append({"path": path.name, "starting_time": {"nanoseconds_since_epoch": first if n else 0},
                      "duration": {"nanoseconds": last - first if n else 0}, "message_count": n})
        if n:
            t_first, t_last = min(t_first, first), max(t_last, last)
    count = sum(t.count for t in topics.values())
    info = bag_information(files[0]["path"], list(topics.values()), t_first if count else 0,
                           t_last - t_first if count else 0, custom)
    info["relative_file_paths"] = [f["path"] for f in files]
    info["files"] = files
    backups = []
    for path in paths:  # pass 2: the same records into an indexed file, with the rosbag2 record
        tmp = path.with_name(path.name + ".reindex")
        _copy_mcap(path, tmp, info, chunk_size, compression)
        if keep_backup:
            backups.append(path.with_name(path.name + ".cut"))
            os.replace(path, backups[-1])
        os.replace(tmp, path)
    write_metadata_file(bag, info)
    return ReindexReport(bag, count, {t.name: t.count for t in topics.values()}, backups)


def _scan_mcap(path: Path, topics: dict[str, _TopicInfo], store) -> tuple[int, int, int]:
    """Count the readable messages of one MCAP file per topic into ``topics``; (count, first, last log time)."""
    schemas: dict[int, str] = {}
    channels: dict[int, str] = {}
    counter = [0]
    first, last = 2**63 - 1, 0
    for record in _records(path, counter):
        if isinstance(record, Schema):
            schemas[record.id] = record.name
        elif isinstance(record, Channel) and record.schema_id in schemas:
            channels[record.id] = record.topic
            if record.topic not in topics:
                try:
                    qos = parse_profiles(record.metadata.get("offered_qos_profiles"), f"{path}: {record.topic}")
                except ValueError as exc:
                    log.warning("%s; recorded without offered QoS", exc)
                    qos = []
                msg_type = schemas[record.schema_id]
                type_hash = record.metadata.get("topic_type_hash") or (
                    store.hash_rihs01(msg_type) if msg_type in store.types else "")
                topics[record.topic] = _TopicInfo(record.topic, msg_type, 0, type_hash, qos)
        elif isinstance(record, Message) and record.channel_id in channels:
            counter[0] += 1
            topics[channels[record.channel_id]].count += 1
            first, last = min(first, record.log_time), max(last, record.log_time)
    return counter[0], first, last


def _copy_mcap(src: Path, dst: Path, info: dict, chunk_size: int, compression: str) -> None:
    """Copy every readable record of ``src`` into a new, indexed MCAP ``dst`` ending with the ``rosbag2`` record."""
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    with open(dst, "wb") as out:
        writer = Writer(out, chunk_size=chunk_size, compression=CHUNK_COMPRESSIONS[compression])
        writer.start(profile="ros2", library="vibro")
        for record in _records(src, [0]):
            if isinstance(record, Schema) and record.id not in schema_ids:
                schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
            elif isinstance(record, Channel) and record.id not in channel_ids and record.schema_id in schema_ids:
                channel_ids[record.id] = writer.register_channel(record.topic, record.message_encoding,
                                                                 schema_ids[record.schema_id], dict(record.metadata))
            elif isinstance(record, Message) and record.channel_id in channel_ids:
                writer.add_message(channel_ids[record.channel_id], log_time=record.log_time, data=record.data,
                                   publish_time=record.publish_time, sequence=record.sequence)
            elif isinstance(record, Metadata) and record.name != "rosbag2":
                writer.add_metadata(record.name, dict(record.metadata))
        writer.add_metadata("rosbag2", {"serialized_metadata": serialized_metadata(info)})
        writer.finish()
