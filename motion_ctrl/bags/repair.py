"""A rosbag2/MCAP bag that survives its recorder being killed: periodic flushing while
recording, and `repair` (``record --repair DIR``, as ``ros2 bag reindex``) afterwards.

Why a repair step and not a bag that is always readable: the `rosbags` reader opens a bag only
through its metadata.yaml, and opens an MCAP file only if the file *ends* with the MCAP footer
and magic (it seeks to the last 37 bytes first; a file without them is "File end magic is
invalid"). A file that is being appended to cannot end with a valid footer while the recorder
writes the next chunk, and SIGKILL can land in the middle of that write, so no ordering of
writes makes every instant of a growing MCAP file readable by `rosbags`. A metadata.yaml
written early would only turn "no metadata.yaml" into a stranger error. So a killed recorder
leaves what a killed `ros2 bag record` leaves, an MCAP file without summary and no
metadata.yaml, and one command makes a complete bag of it.

Flushing (`flush`, called by the recorder every FLUSH_PERIOD): rosbags' MCAP writer collects
messages in an in-memory chunk and writes it out only when it passes 1 MiB, which at the
slide's ~6000 messages/s is every ~1.5 s, and then into an 8 KiB-buffered file. `flush` closes
the pending chunk and flushes the file, so what the recorder had written reaches the kernel
at least every FLUSH_PERIOD: a SIGKILL (which does not lose the kernel's page cache) then
costs at most the messages of the last FLUSH_PERIOD. (A power cut can cost more: no fsync.)
This uses two internals of rosbags' McapWriter (`storage.chunk`, `storage.close_chunk()`,
`storage.bio`), pinned in requirements.txt and checked by `check_flushable` when the bag opens.

Repair (`repair`): reads the MCAP file record by record (a small parser of its own: the `mcap`
package's reader returns a short read as data and would hand out a torn last message), keeps
every complete Schema, Channel and Message record, including the complete messages of a last
chunk that was cut off (chunks are written uncompressed), stops at the first incomplete or
inconsistent record, and rewrites the file through rosbags' Writer: a complete MCAP with chunk
indexes and summary, and the metadata.yaml (topics, types, offered QoS, counts, start and
duration). The new file replaces the old one atomically (same directory, os.replace); what it
leaves out is only the unreadable tail. Topics whose channel record was still in the unwritten
chunk (no message flushed yet) are not in the repaired bag. The recorder holds an flock on its
file (`lock`), which the kernel drops when it dies: `repair` refuses a file still being written.
"""
from __future__ import annotations

import fcntl
import mmap
import os
import pathlib
import shutil
import struct
from dataclasses import dataclass, field

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

FLUSH_PERIOD = 0.5          # s between forced chunk closes while recording
MAGIC = b'\x89MCAP0\r\n'

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, \
    0x05, 0x06
OP_DATA_END = 0x0F
OP_MAX = 0x0F               # highest opcode of the MCAP spec; 0 and above are not records


class RepairError(Exception):
    """The directory cannot be repaired: one line for the user, exit code 2."""


# -- while recording ------------------------------------------------------------------------------
def check_flushable(writer) -> None:
    """Raise RuntimeError unless `writer` (an open rosbags Writer with MCAP storage) has the
    internals `flush` uses (a rosbags version other than the pinned one may not)."""
    storage = getattr(writer, 'storage', None)
    chunk = getattr(storage, 'chunk', None)
    if not (callable(getattr(storage, 'close_chunk', None)) and hasattr(chunk, 'msgs')
            and callable(getattr(getattr(storage, 'bio', None), 'flush', None))):
        raise RuntimeError('rosbags McapWriter lacks chunk/close_chunk/bio: the recorder '
                           'cannot flush periodically (rosbags version not the pinned one?)')


def lock(writer) -> None:
    """Take an exclusive flock on the MCAP file while recording: `repair` refuses a file a live
    recorder is writing. The kernel drops the lock when the process dies, SIGKILL included."""
    fcntl.flock(writer.storage.bio.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)


def flush(writer) -> bool:
    """Write the writer's pending chunk (if it holds messages) and flush the file to the kernel.
    Returns whether a chunk was written."""
    storage = writer.storage
    if storage is None:
        return False
    wrote = bool(storage.chunk.msgs)
    if wrote:
        storage.close_chunk()
    storage.bio.flush()
    return wrote


# -- reading what was written ---------------------------------------------------------------------
class _Stop(Exception):
    """The data ends (incomplete record) or stops making sense at this record."""


@dataclass
class Scan:
    """What `read_records` found in an MCAP file."""
    schemas: dict = field(default_factory=dict)       # id -> (name, encoding, data)
    channels: dict = field(default_factory=dict)      # id -> (schema_id, topic, encoding, meta)
    complete: bool = False     # the data section ended properly (DataEnd or Footer)
    end: int = 0               # file offset after the last record kept (top level)
    size: int = 0              # file size
    stopped: str = ''          # why the reading stopped early
    partial_chunk: int = 0     # messages taken from a chunk that was cut off
    orphans: int = 0           # messages on an unknown channel (left out)


def _string(buf, pos, end) -> tuple[str, int]:
    if pos + 4 > end:
        raise _Stop('string length past the record')
    (n,) = struct.unpack_from('<I', buf, pos)
    pos += 4
    if pos + n > end:
        raise _Stop('string past the record')
    try:
        return bytes(buf[pos:pos + n]).decode('utf-8'), pos + n
    except UnicodeDecodeError:
        raise _Stop('a string that is not UTF-8') from None


def _bytes(buf, pos, end, width='<I') -> tuple[bytes, int]:
    size = struct.calcsize(width)
    if pos + size > end:
        raise _Stop('bytes length past the record')
    (n,) = struct.unpack_from(width, buf, pos)
    pos += size
    if pos + n > end:
        raise _Stop('bytes past the record')
    return bytes(buf[pos:pos + n]), pos + n


def _records(buf, pos: int, end: int, scan: Scan, top: bool):
    """Yield (opcode, body_start, body_end) for each complete record in buf[pos:end]. At an
    incomplete record: a top-level uncompressed chunk yields ('partial', ...) for its available
    records; then stops (scan.stopped says why)."""
    while pos < end:
        if end - pos < 9:
            scan.stopped = f'incomplete record header at byte {pos}'
            return
        op = buf[pos]
        (length,) = struct.unpack_from('<Q', buf, pos + 1)
        body = pos + 9
        if op == 0 or op > OP_MAX:
            scan.stopped = f'no MCAP record at byte {pos} (opcode {op:#x})'
            return
        if body + length > end:
            scan.stopped = (f'{"chunk" if op == OP_CHUNK else "record"} at byte {pos} cut off '
                            f'({end - body} of {length} bytes)')
            if top and op == OP_CHUNK:
                yield 'partial', body, end
            return
        yield op, body, body + length
        pos = body + length
        if top:
            scan.end = pos


def _chunk_records(buf, body: int, body_end: int, partial: bool) -> tuple[int, int]:
    """(start, end) of the records inside a chunk record's body (clipped to body_end when the
    chunk was cut off). Raises _Stop for a compressed chunk that was cut off."""
    pos = body + 8 + 8 + 8 + 4          # start time, end time, uncompressed size, crc
    compression, pos = _string(buf, pos, body_end)
    if pos + 8 > body_end:
        raise _Stop('chunk cut off in its header')
    (n,) = struct.unpack_from('<Q', buf, pos)
    pos += 8
    if compression:
        if partial:
            raise _Stop(f'{compression} chunk cut off: its messages are lost')
        raise _Stop(f'{compression}-compressed chunk: not supported here')
    return pos, min(pos + n, body_end)


def read_records(buf, scan: Scan):
    """Yield ('schema', id) / ('channel', id) / ('message', channel_id, log_time, data) for every
    complete record of an MCAP file in `buf`, filling scan.schemas / scan.channels."""
    if len(buf) < 8 or bytes(buf[:8]) != MAGIC:
        raise RepairError('not an MCAP file (no MCAP magic at the start)')
    scan.size = len(buf)
    scan.end = 8
    try:
        for op, a, b in _records(buf, 8, len(buf), scan, top=True):
            if op == OP_HEADER:
                _check_profile(buf, a, b)
            elif op in (OP_DATA_END, OP_FOOTER):
                scan.complete = True
                return
            elif op == OP_CHUNK or op == 'partial':
                yield from _chunk_items(buf, a, b, op == 'partial', scan)
            else:
                yield from _items(buf, op, a, b, scan)
    except _Stop as e:
        scan.stopped = str(e)


def _check_profile(buf, a: int, b: int) -> None:
    """The Header record's profile must be 'ros2' (a rosbag2 MCAP file)."""
    try:
        profile, _ = _string(buf, a, b)
    except _Stop:
        profile = ''
    if profile != 'ros2':
        raise RepairError(f'MCAP profile {profile!r}, not a ros2 bag')


def _chunk_items(buf, a: int, b: int, partial: bool, scan: Scan):
    """The items of the records inside a Chunk record's body buf[a:b] (`partial`: a chunk that
    was cut off, whose complete records are kept and counted in scan.partial_chunk)."""
    lo, hi = _chunk_records(buf, a, b, partial)
    inner = Scan()          # only for its stopped / unused bookkeeping
    for iop, ia, ib in _records(buf, lo, hi, inner, top=False):
        for item in _items(buf, iop, ia, ib, scan):
            if partial and item[0] == 'message':
                scan.partial_chunk += 1
            yield item
    if inner.stopped and not partial:
        raise _Stop(f'inside the chunk at byte {a - 9}: {inner.stopped}')


def _items(buf, op, a: int, b: int, scan: Scan) -> list:
    """The item of one Schema, Channel or Message record with body buf[a:b] (none for other
    records, a channel seen before, a message on an unknown channel)."""
    if op == OP_SCHEMA:
        return [('schema', _schema(buf, a, b, scan))]
    if op == OP_CHANNEL:
        cid = _channel(buf, a, b, scan)
        return [] if cid is None else [('channel', cid)]
    if op == OP_MESSAGE:
        if b - a < 22:
            raise _Stop('short message record')
        cid, _seq, log_time = struct.unpack_from('<HIQ', buf, a)
        if cid not in scan.channels:
            scan.orphans += 1
            return []
        return [('message', cid, log_time, bytes(buf[a + 22:b]))]
    return []


def _schema(buf, a: int, b: int, scan: Scan) -> int:
    """Read a Schema record (id, name, encoding, data) into scan.schemas; its id."""
    if b - a < 2:
        raise _Stop('short schema record')
    (sid,) = struct.unpack_from('<H', buf, a)
    name, p = _string(buf, a + 2, b)
    encoding, p = _string(buf, p, b)
    data, p = _bytes(buf, p, b)
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError:
        raise _Stop('a schema that is not UTF-8') from None
    scan.schemas.setdefault(sid, (name, encoding, text))
    return sid


def _channel(buf, a: int, b: int, scan: Scan) -> int | None:
    """Read a Channel record (id, schema id, topic, encoding, metadata) into scan.channels; its
    id, None when the id was seen before."""
    if b - a < 4:
        raise _Stop('short channel record')
    cid, sid = struct.unpack_from('<HH', buf, a)
    topic, p = _string(buf, a + 4, b)
    encoding, p = _string(buf, p, b)
    meta_raw, p = _bytes(buf, p, b)
    meta, q = {}, 0
    while q < len(meta_raw):
        k, q = _string(meta_raw, q, len(meta_raw))
        v, q = _string(meta_raw, q, len(meta_raw))
        meta[k] = v
    if cid in scan.channels:
        return None
    scan.channels[cid] = (sid, topic, encoding, meta)
    return cid


# -- repair ---------------------------------------------------------------------------------------
@dataclass
class RepairResult:
    """What `repair` kept, and where and why the file stopped; `summary` is what
    `record --repair` prints."""
    path: pathlib.Path
    counts: dict            # topic -> messages kept
    types: dict             # topic -> type
    start_ns: int | None
    end_ns: int | None
    kept_bytes: int
    size: int
    partial_chunk: int
    stopped: str
    complete: bool

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def summary(self, prog: str = 'record') -> str:
        span = (self.end_ns - self.start_ns) * 1e-9 \
            if self.end_ns is not None and self.start_ns is not None else 0.0
        lines = [f'{prog}: repaired {self.path}: {self.total} messages on {len(self.counts)} '
                 f'topics over {span:.1f} s']
        if self.complete:
            lines.append(f'{prog}: the MCAP file was complete; metadata.yaml rewritten')
        elif self.kept_bytes == self.size:
            lines.append(f'{prog}: the MCAP file ends after a complete record ({self.size} '
                         f'bytes, no summary): every message kept')
        else:
            lines.append(f'{prog}: the MCAP file stops at byte {self.kept_bytes} of {self.size} '
                         f'({self.stopped}); every complete message before it kept'
                         + (f', {self.partial_chunk} of them from the cut-off chunk'
                            if self.partial_chunk else ''))
        width = max([len(t) for t in self.counts] + [5])
        for topic in sorted(self.counts):
            lines.append(f'  {topic:<{width}}  {self.counts[topic]:>8}  {self.types[topic]}')
        return '\n'.join(lines)


def _rihs01(msgtype: str, msgdef: str) -> str:
    """The type hash for the metadata (the MCAP file does not hold it)."""
    kilted = get_typestore(Stores.ROS2_KILTED)
    try:
        if msgtype in kilted.types and \
                kilted.generate_msgdef(msgtype, ros_version=2)[0] == msgdef:
            return kilted.hash_rihs01(msgtype)     # what the recorder wrote: no parsing
    except Exception:
        pass
    try:
        ts = get_typestore(Stores.EMPTY)
        ts.register(get_types_from_msg(msgdef, msgtype))
        return ts.hash_rihs01(msgtype)
    except Exception:
        return ''


def find_mcap(bag_dir: pathlib.Path) -> pathlib.Path:
    """The one MCAP file of a bag directory (RepairError for none or several)."""
    if not bag_dir.is_dir():
        raise RepairError(f'{bag_dir}: no such bag directory')
    files = sorted(p for p in bag_dir.glob('*.mcap') if p.is_file())
    if len(files) != 1:
        raise RepairError(f'{bag_dir}: {"no" if not files else len(files)} .mcap files '
                          f'(repair handles a bag of one MCAP file)')
    return files[0]


def needs_repair(bag_dir) -> bool:
    """A directory holding one MCAP file and no metadata.yaml: a recorder killed before it
    closed the bag."""
    d = pathlib.Path(bag_dir)
    return (d.is_dir() and not (d / 'metadata.yaml').exists()
            and any(p.is_file() for p in d.glob('*.mcap')))


def repair(bag_dir) -> RepairResult:
    """Make a complete rosbag2 bag (MCAP with summary + metadata.yaml) of what a killed recorder
    left in `bag_dir`. Raises RepairError (one line) when there is nothing to repair from."""
    bag_dir = pathlib.Path(bag_dir)
    src = find_mcap(bag_dir)
    if (bag_dir / 'metadata.yaml').exists():
        raise RepairError(f'{bag_dir}: has a metadata.yaml already (a closed bag: nothing to '
                          f'repair; delete metadata.yaml to rebuild it)')
    work = bag_dir / '.repair'
    if work.exists():
        shutil.rmtree(work)            # left by a repair that was itself interrupted
    writer = Writer(work / src.stem, version=Writer.VERSION_LATEST,
                    storage_plugin=StoragePlugin.MCAP)
    scan = Scan()
    with open(src, 'rb') as f:
        size = _size_unlocked(f, src)
        buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        try:
            writer.open()
            copy = _copy(buf, writer, scan)
            if not scan.complete:
                writer.set_custom_data(
                    'motion_ctrl.repaired',
                    f'record --repair: kept {scan.end} of {size} bytes ({scan.stopped})')
            writer.close()
        except BaseException:
            writer.abort()
            shutil.rmtree(work, ignore_errors=True)
            raise
        finally:
            buf.close()
    new_dir = work / src.stem
    os.replace(new_dir / f'{src.stem}.mcap', src)
    os.replace(new_dir / 'metadata.yaml', bag_dir / 'metadata.yaml')
    shutil.rmtree(work)
    kept = size if scan.complete else scan.end
    return RepairResult(bag_dir, copy.counts, copy.types, copy.start, copy.end, kept, size,
                        scan.partial_chunk, scan.stopped, scan.complete)


def _size_unlocked(f, src: pathlib.Path) -> int:
    """The size of the open MCAP file `f`; RepairError while a recorder holds its lock (`lock`)
    or when it is empty."""
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        raise RepairError(f'{src}: a recorder is still writing it (file locked); stop it '
                          f'first') from None
    size = os.fstat(f.fileno()).st_size
    if size == 0:
        raise RepairError(f'{src}: empty file (the recorder wrote nothing)')
    return size


@dataclass
class _Copy:
    """What `_copy` wrote into the new bag."""
    conns: dict = field(default_factory=dict)     # channel id -> rosbags connection
    counts: dict = field(default_factory=dict)    # topic -> messages written
    types: dict = field(default_factory=dict)     # topic -> type
    start: int | None = None                      # first and last log time [ns]
    end: int | None = None


def _copy(buf, writer, scan: Scan) -> _Copy:
    """Write every complete channel (with a schema) and message of the MCAP file in `buf`
    through the open rosbags `writer`."""
    copy = _Copy()
    for item in read_records(buf, scan):
        if item[0] == 'channel':
            _add_connection(writer, scan, item[1], copy)
        elif item[0] == 'message':
            _, cid, log_time, data = item
            conn = copy.conns.get(cid)
            if conn is None:
                continue
            writer.write(conn, log_time, data)
            copy.counts[conn.topic] += 1
            copy.start = log_time if copy.start is None else min(copy.start, log_time)
            copy.end = log_time if copy.end is None else max(copy.end, log_time)
    return copy


def _add_connection(writer, scan: Scan, cid: int, copy: _Copy) -> None:
    """The writer's connection for channel `cid`: its topic, type, schema, type hash and the
    offered QoS of its metadata (a schemaless channel is left out: rosbags cannot write it)."""
    sid, topic, encoding, meta = scan.channels[cid]
    name, _fmt, msgdef = scan.schemas.get(sid, ('', '', ''))
    if not name:
        return
    try:
        qos = parse_qos(meta.get('offered_qos_profiles', ''))
    except Exception:
        qos = []
    copy.conns[cid] = writer.add_connection(
        topic, name, msgdef=msgdef, rihs01=_rihs01(name, msgdef),
        serialization_format=encoding, offered_qos_profiles=qos)
    copy.counts.setdefault(topic, 0)
    copy.types[topic] = name
