# Copyright 2026 pmba_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""Replay integrity on damaged recordings, full disks, interrupts and shared folders (#13)."""

from __future__ import annotations

from collections.abc import Iterator
import errno
import json
import logging
import os
from pathlib import Path
import random
import re
import signal
import struct
import subprocess
import sys
import time
from typing import Any

from pmba_ros import replay as replay_mod
from pmba_ros.cli.main import main
from pmba_ros.errors import BagError
from pmba_ros.eval.trajectory import read_tum
from pmba_ros.io import ply
from pmba_ros.io.atomic import deferred_interrupts
from pmba_ros.io.bag_writer import BagWriter, open_writer
from pmba_ros.io.bags import iter_messages, iter_serialized, list_topics, ReadStats
from pmba_ros.io.output_dir import output_lock
from pmba_ros.replay import replay
from pmba_ros.sim.bag import write_sequence_bag
from pmba_ros.sim.sequence import simulate_sequence
import pytest

from .test_replay import _backend, StubLogic

N_KF = 20
N_MSGS = 3 * N_KF  # tracks, keyframe pose and camera info per keyframe


@pytest.fixture(autouse=True)
def stub(monkeypatch: pytest.MonkeyPatch) -> None:
    """Use the replay tests' stand-in back-end (integrity does not depend on the solver)."""
    monkeypatch.setattr(replay_mod, '_make_logic',
                        lambda config: StubLogic(config, _backend()))


@pytest.fixture
def sigint_raises() -> Iterator[None]:
    """Python's own SIGINT handler, whatever the runner inherited (a background job ignores it)."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Write a 20-keyframe simulated street as a bare MCAP file."""
    path = tmp_path_factory.mktemp('integrity') / 'street.mcap'
    write_sequence_bag(simulate_sequence('street', n_keyframes=N_KF, seed=0), path)
    return path


def _flipped(data: bytes, seed: int) -> bytes:
    """Return ``data`` with four bytes in its middle half inverted."""
    rng = random.Random(seed)
    out = bytearray(data)
    for _ in range(4):
        i = rng.randrange(len(out) // 4, 3 * len(out) // 4)
        out[i] ^= 0xFF
    return bytes(out)


def _read_count(path: Path) -> int | None:
    """Return how many messages a bag yields, or None if reading raises."""
    try:
        return sum(1 for _ in iter_messages([path]))
    except BagError:
        return None


@pytest.fixture(scope='module')
def silently_short_bag(bag: Path) -> Path:
    """Find flipped bytes that make the reader stop early without an error."""
    data = bag.read_bytes()
    damaged = bag.with_name('short.mcap')
    announced = sum(info.count for info in list_topics([bag]).values())
    for seed in range(300):
        damaged.write_bytes(_flipped(data, seed))
        try:
            ok = list_topics([damaged]) and (_read_count(damaged) or announced) < announced
        except BagError:
            ok = False
        if ok:
            return damaged
    pytest.fail('no flip pattern gave a silently short read')


def test_silently_short_bag_is_reported_incomplete(
        silently_short_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Flipped bytes that end the reading early: exit 3, warning, `complete: false`."""
    out = tmp_path / 'o'
    rc = main(['replay', str(silently_short_bag), '--out', str(out), '--quiet'])
    assert rc == 3
    data = json.loads((out / 'report.json').read_text())
    read = data['messages_read']
    assert data['complete'] is False and data['input_complete'] is False
    assert data['messages_announced'] == N_MSGS and read < N_MSGS
    assert any(f'only {read} were read' in w for w in data['warnings'])
    assert f'read {read} of {N_MSGS} announced messages' in capsys.readouterr().err


def _bag_with_garbage_message(bag: Path, out: Path, garbage_index: int) -> None:
    """Copy ``bag`` with the raw bytes of the ``garbage_index``-th tracks message damaged."""
    n_tracks = 0
    with open_writer(out) as writer:
        for message in iter_messages([bag]):
            if message.topic == '/features':
                n_tracks += 1
                if n_tracks == garbage_index + 1:
                    # Raw bytes that are no CDR PointCloud, written past the serializer.
                    conn = writer._connections[message.topic]
                    writer._writer.write(conn, message.log_time_ns, b'\x00\x01\x00\x00\xff')
                    continue
            writer.write(message.topic, message.msg, message.log_time_ns)


def test_undecodable_message_is_skipped_and_counted(bag: Path, tmp_path: Path) -> None:
    """One undecodable message no longer ends the replay: the rest is processed."""
    damaged = tmp_path / 'garbage.mcap'
    _bag_with_garbage_message(bag, damaged, garbage_index=5)
    out = tmp_path / 'o'
    report = replay([damaged], out)
    assert report.messages_undecodable == 1
    assert report.messages_read == N_MSGS - 1
    assert report.keyframes_in == N_KF
    assert not report.complete and not report.input_complete
    assert len(read_tum(out / 'keyframes_optimized.tum')) == N_KF
    data = json.loads((out / 'report.json').read_text())
    assert data['warnings'][0].startswith('1 messages skipped (they do not deserialize); '
                                          'first:')
    assert 'sensor_msgs/msg/PointCloud message on /features' in data['warnings'][0]


def test_reorder_buffer_is_flushed_when_reading_stops(bag: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """A bag that breaks after 45 messages: all 45 are processed (the buffer holds 256)."""
    real = replay_mod.iter_messages

    def breaking(paths: Any, topics: Any = None, *, damage: ReadStats | None = None,
                 points_as_arrays: bool = False) -> Iterator[Any]:
        for i, message in enumerate(real(paths, topics, points_as_arrays=points_as_arrays)):
            if i == 45:
                assert damage is not None
                damage.damaged_parts = 1
                damage.first_damage = 'street.mcap: bag is corrupt or truncated: test'
                return
            yield message

    monkeypatch.setattr(replay_mod, 'iter_messages', breaking)
    report = replay([bag], tmp_path / 'o')
    assert report.messages_in == 45 == report.messages_read
    assert report.keyframes_in == 15
    assert report.read_error is not None and not report.complete
    assert any(w.startswith('1 damaged or incomplete part(s) of the recording read around; '
                            'first: street.mcap') for w in report.warnings)


def test_bag_broken_before_any_message_is_an_error(bag: Path, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Nothing readable at all stays an error (exit 1), with `complete: false`."""
    def broken(paths: Any, topics: Any = None, *, damage: ReadStats | None = None,
               points_as_arrays: bool = False) -> Iterator[Any]:
        assert damage is not None
        damage.damaged_parts = 1
        damage.first_damage = 'street.mcap: bag is corrupt or truncated: zstd'
        yield from ()

    monkeypatch.setattr(replay_mod, 'iter_messages', broken)
    out = tmp_path / 'o'
    with pytest.raises(BagError, match='corrupt or truncated: zstd'):
        replay([bag], out)
    assert json.loads((out / 'report.json').read_text())['complete'] is False


def _disk_full(*args: Any, **kwargs: Any) -> None:
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), 'landmarks.ply')


def test_failed_replay_replaces_an_earlier_runs_outputs(bag: Path, tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str],
                                                        ) -> None:
    """Disk full on the PLY: the real cause is reported and no old output survives."""
    out = tmp_path / 'o'
    assert replay([bag], out).complete
    assert (out / 'landmarks.ply').exists()
    monkeypatch.setattr(ply, 'write_ply', _disk_full)
    rc = main(['replay', str(bag), '--out', str(out), '--quiet'])
    assert rc == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ['error: landmarks.ply: No space left on device']
    data = json.loads((out / 'report.json').read_text())
    assert data['complete'] is False
    assert data['error'] == 'landmarks.ply: No space left on device'
    assert not (out / 'landmarks.ply').exists()
    assert len(read_tum(out / 'keyframes_frontend.tum')) == N_KF
    assert not [p for p in out.iterdir() if '.tmp' in p.name]


def test_disk_full_in_the_result_bag_is_the_reported_cause(bag: Path, tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch,
                                                           ) -> None:
    """ENOSPC while writing result.mcap is what the caller sees, not a later error."""
    def full(self: BagWriter, *args: Any, **kwargs: Any) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(BagWriter, 'write', full)
    out = tmp_path / 'o'
    with pytest.raises(OSError, match='No space left on device') as exc:
        replay([bag], out)
    assert exc.value.errno == errno.ENOSPC
    data = json.loads((out / 'report.json').read_text())
    assert data['complete'] is False and data['error'] == 'No space left on device'


def test_second_replay_into_a_folder_in_use_is_refused(bag: Path, tmp_path: Path) -> None:
    """The lock file makes a concurrent replay into the same folder a clear error."""
    out = tmp_path / 'o'
    out.mkdir()
    with output_lock(out), pytest.raises(BagError, match=r'another replay \(process \d+\)'):
        replay([bag], out)
    assert not (out / 'report.json').exists()
    assert replay([bag], out).complete  # released afterwards


@pytest.mark.usefixtures('sigint_raises')
def test_interrupts_wait_for_the_block() -> None:
    """SIGINT inside deferred_interrupts is delivered when the block ends."""
    done = []
    with pytest.raises(KeyboardInterrupt), deferred_interrupts():
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)
        done.append(True)
    assert done == [True]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.usefixtures('sigint_raises')
def test_interrupt_while_writing_outputs_lets_them_finish(bag: Path, tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch,
                                                          ) -> None:
    """Ctrl-C during the output writing: every output and the report are still written."""
    real = ply.write_ply

    def interrupted(*args: Any, **kwargs: Any) -> None:
        os.kill(os.getpid(), signal.SIGINT)
        real(*args, **kwargs)

    monkeypatch.setattr(ply, 'write_ply', interrupted)
    out = tmp_path / 'o'
    with pytest.raises(KeyboardInterrupt):
        replay([bag], out)
    assert (out / 'landmarks.ply').exists()
    data = json.loads((out / 'report.json').read_text())
    assert data['complete'] is True  # the replay itself had finished


@pytest.mark.parametrize('delay_s', [1.5, 3.0])
def test_sigint_storm_leaves_a_consistent_folder(bag: Path, tmp_path: Path,
                                                 delay_s: float) -> None:
    """SIGINT every 20 ms into a replay: no traceback, nothing half written, a valid report."""
    out = tmp_path / 'o'
    proc = subprocess.Popen([sys.executable, '-m', 'pmba_ros', 'replay', str(bag), '--out',
                             str(out), '--quiet'], stderr=subprocess.PIPE, text=True)
    time.sleep(delay_s)
    while proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        time.sleep(0.02)
    _, err = proc.communicate(timeout=60)
    # -2: ended by the signal itself, which a shell also reports as 130.
    assert proc.returncode in (0, 130, -signal.SIGINT), err
    # Python's own limit: an interrupt that lands in a finalizer (llvmlite's __del__) is
    # printed as ignored there, and the program goes on; nothing else may be printed.
    ignored = re.compile(r'Exception ignored in: <function [^\n]*__del__[^\n]*\n'
                         r'Traceback \(most recent call last\):\n(  .*\n)+KeyboardInterrupt: ?\n')
    rest = ignored.sub('', err)
    assert 'Traceback' not in rest and 'KeyboardInterrupt' not in rest
    names = {p.name for p in out.iterdir()} if out.exists() else set()
    assert not [n for n in names if n.endswith(('.partial', '.tmp')) or '.tmp.' in n]
    if 'report.json' in names:
        data = json.loads((out / 'report.json').read_text())
        # Interrupted while writing, the finished replay's report is still complete.
        assert data['complete'] or (proc.returncode != 0 and data['error'] == 'interrupted')
        for key in ('frontend_tum', 'optimized_tum', 'landmarks_ply', 'result_bag'):
            if key in data['files'] and key != 'result_bag':
                assert Path(data['files'][key]).exists()
    if 'result.mcap' in names:
        list_topics([out / 'result.mcap'])  # finalized: readable


def _rechunked(src: Path, dst: Path, chunk_size: int) -> None:
    """Copy an MCAP file with chunks of ``chunk_size`` bytes (a long recording has many)."""
    from mcap.records import Channel, Header, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    with src.open('rb') as stream, dst.open('wb') as out:
        writer = Writer(out, chunk_size=chunk_size)
        ids: dict[tuple[str, int], int] = {}
        for rec in StreamReader(stream).records:
            if isinstance(rec, Header):
                writer.start(rec.profile, rec.library)
            elif isinstance(rec, Schema) and ('s', rec.id) not in ids:
                ids['s', rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and ('c', rec.id) not in ids:
                ids['c', rec.id] = writer.register_channel(
                    rec.topic, rec.message_encoding, ids['s', rec.schema_id], rec.metadata)
            elif isinstance(rec, Message):
                writer.add_message(ids['c', rec.channel_id], rec.log_time, rec.data,
                                   rec.publish_time, rec.sequence)
        writer.finish()


def test_truncated_recording_keeps_the_keyframes_before_the_cut(bag: Path,
                                                                tmp_path: Path) -> None:
    """A recorder killed mid-run: the keyframes before the cut are replayed, damage reported.

    Before, the file without its index was refused whole ("File end magic is invalid").
    """
    chunked = tmp_path / 'chunked.mcap'
    _rechunked(bag, chunked, 4096)
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(chunked.read_bytes()[: chunked.stat().st_size * 6 // 10])
    out = tmp_path / 'o'
    report = replay([cut], out)
    data = json.loads((out / 'report.json').read_text())
    assert not data['complete'] and not data['input_complete'] and data['damaged_parts'] == 1
    assert 'cut.mcap: cannot be opened' in data['read_error']
    assert 'the rest of the file is lost' in data['read_error']
    assert N_KF // 3 < report.keyframes_out < N_KF
    assert len(read_tum(out / 'keyframes_frontend.tum')) == report.keyframes_out


def test_killed_recording_whose_chunk_length_is_damaged_replays_whole(bag: Path,
                                                                      tmp_path: Path) -> None:
    """A recorder killed after its one chunk, whose length field reads 2**63: every keyframe.

    The chunk holds the schemas and channels: before, the file was refused whole (exit 1,
    "cannot open bag (...): File end magic is invalid."). Now it is read by the length its
    head gives, and the report says so (exit 3, as for any damaged recording).
    """
    data = bytearray(bag.read_bytes())
    chunk = 8 + 9 + struct.unpack_from('<Q', data, 8 + 1)[0]   # past the magic and header
    assert data[chunk] == 0x06
    struct.pack_into('<Q', data, chunk + 1, 2**63)
    killed = tmp_path / 'killed.mcap'
    killed.write_bytes(data[:struct.unpack_from('<Q', data, len(data) - 37 + 9)[0]])
    out = tmp_path / 'o'
    assert main(['replay', str(killed), '--out', str(out), '--quiet']) == 3
    report = json.loads((out / 'report.json').read_text())
    assert report['damaged_parts'] == 1 and report['read_error'].startswith(str(killed))
    assert f'the chunk at byte {chunk} read by the length its head gives' in report['read_error']
    assert len(read_tum(out / 'keyframes_frontend.tum')) == N_KF


def _damaged(bag: Path, folder: Path, kind: str) -> Path:
    """Return the street recorded as ``kind`` and damaged as a killed recorder leaves it."""
    from rosbags.convert.converter import convert
    from rosbags.typesys import get_typestore, Stores

    if kind == 'ros1_active':
        ros1 = folder / 'street.bag'
        convert([bag], ros1, 'sqlite3', 9, None, 'file', None,
                get_typestore(Stores.ROS1_NOETIC), [], [], [], [])
        data = bytearray(ros1.read_bytes())
        field = data.index(b'index_pos=') + len(b'index_pos=')
        (index_pos,) = struct.unpack_from('<Q', data, field)
        data[field: field + 8] = bytes(8)
        active = folder / 'run.bag.active'
        active.write_bytes(data[:index_pos])
        return active
    rec = folder / 'rec'
    convert([bag], rec, 'sqlite3', 9, None, 'file', None, None, [], [], [], [])
    (rec / 'metadata.yaml').unlink()
    if kind == 'db3_cut':
        db3 = rec / 'rec.db3'
        db3.write_bytes(db3.read_bytes()[: db3.stat().st_size * 6 // 10 + 777])
    return rec


@pytest.mark.parametrize('kind', ['no_metadata', 'db3_cut', 'ros1_active'])
def test_killed_recorders_recording_replays_what_it_holds(bag: Path, tmp_path: Path,
                                                          kind: str) -> None:
    """A killed recorder's recording: what it wrote is replayed, exit 3, the damage reported.

    A rosbag2 folder without metadata.yaml (its SQLite file whole or cut short), a ROS 1
    ``.bag.active`` without its index. Before, the cut SQLite file and the ROS 1 bag were
    refused whole, and the folder without metadata.yaml replayed as complete.
    """
    recording = _damaged(bag, tmp_path, kind)
    out = tmp_path / 'o'
    assert main(['replay', str(recording), '--out', str(out), '--quiet']) == 3
    data = json.loads((out / 'report.json').read_text())
    assert not data['complete'] and data['damaged_parts'] >= 1
    assert data['read_error'].startswith(str(recording))
    kept = len(read_tum(out / 'keyframes_frontend.tum'))
    if kind == 'db3_cut':
        assert N_KF // 3 < kept < N_KF
        assert 'the rest of the file is lost' in data['read_error']
        assert any('no metadata.yaml' in w for w in data['warnings'])
    else:
        assert kept == N_KF


def test_play_reads_a_damaged_recording_as_replay_does(bag: Path, tmp_path: Path,
                                                       caplog: pytest.LogCaptureFixture) -> None:
    """``pmba play``'s reader: a cut MCAP file up to the cut with a warning, a ROS 1 bag refused.

    Before, play opened recordings without salvage: the cut file was refused whole.
    """
    whole = sum(1 for _ in iter_serialized([bag]))
    chunked = tmp_path / 'chunked.mcap'
    _rechunked(bag, chunked, 4096)
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(chunked.read_bytes()[: chunked.stat().st_size * 6 // 10])
    with caplog.at_level(logging.WARNING, logger='pmba_ros.io'):
        played = list(iter_serialized([cut]))
    assert whole // 3 < len(played) < whole
    assert [t for _, t, _ in played] == sorted(t for _, t, _ in played)
    assert any('cut.mcap: cannot be opened' in r.getMessage() for r in caplog.records)
    with pytest.raises(BagError, match='ROS 1 bag cannot be played'):
        list(iter_serialized([_damaged(bag, tmp_path, 'ros1_active')]))


def test_play_salvages_a_damaged_recording_once_and_warns_once_per_damage(
        bag: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``pmba play --loop`` of a cut file: one salvage, one warning, every pass the same.

    Before, the topics and every pass opened the recording again: the cut file was salvaged
    once per pass plus once, and its damage warned twice per pass plus once.
    """
    import itertools

    from pmba_ros import node as node_mod
    from pmba_ros.io import salvage

    chunked = tmp_path / 'chunked.mcap'
    _rechunked(bag, chunked, 4096)
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(chunked.read_bytes()[: chunked.stat().st_size * 6 // 10])
    one_pass = list(iter_serialized([cut]))
    passes: list[list[tuple[str, int, bytes]]] = []

    def play_messages(messages: Iterator[tuple[str, int, bytes]], *_: Any, **__: Any) -> int:
        taken = list(itertools.islice(messages, 3 * len(one_pass)))
        passes.extend(taken[i:i + len(one_pass)] for i in range(0, len(taken), len(one_pass)))
        return len(taken)

    salvaged = []
    readable_parts = salvage.readable_parts
    monkeypatch.setattr(salvage, 'readable_parts',
                        lambda *a: salvaged.append(1) or readable_parts(*a))
    monkeypatch.setattr(node_mod, 'play_messages', play_messages)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger='pmba_ros'):
        assert main(['play', str(cut), '--loop']) == 0
    assert passes == [one_pass] * 3
    assert len(salvaged) == 1
    assert sum('cut.mcap: cannot be opened' in r.getMessage() for r in caplog.records) == 1
