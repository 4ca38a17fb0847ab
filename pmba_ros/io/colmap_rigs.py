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
"""Read and write COLMAP rigs and frames (``rigs``, ``frames``; text or binary, COLMAP >= 3.12).

A rig is a reference sensor and other sensors, each with its ``sensor_from_rig`` pose (or
none, unknown); a frame is one ``rig_from_world`` pose and the data of its sensors taken at
once: (sensor type, sensor id, data id), for a camera the image id. An image's pose is
``cam_from_world = sensor_from_rig * rig_from_world`` (the reference sensor's offset is the
identity). The files are validated against the model's images (each image in one frame at
most, through its own camera, of a sensor of the frame's rig); every error names the file.
How a rig becomes one pose per frame of a problem: :mod:`pmba_ros.io.colmap_rig_problem`.

Format reference: COLMAP's ``src/colmap/scene/reconstruction_io_binary.cc`` and
``reconstruction_io_text.cc`` (``ReadRigs*``, ``ReadFrames*`` and their writers).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import struct
from typing import BinaryIO, TYPE_CHECKING

import numpy as np
from pmba_ros.errors import FormatError
from pmba_ros.io.colmap_files import BinaryReader, check_new_id, data_lines, integers, numbers
from pmba_ros.io.colmap_poses import check_translation

if TYPE_CHECKING:
    from os import PathLike

    from pmba_ros._typing import FloatArray, IntArray
    from pmba_ros.io.colmap import ColmapImage

__all__ = ['CAMERA', 'ColmapFrame', 'ColmapRig', 'ColmapRigs', 'ColmapSensor', 'read_rigs',
           'write_rigs']

#: COLMAP's sensor types (``SensorType``) by their number in the binary files.
SENSOR_TYPES: dict[int, str] = {-1: 'INVALID', 0: 'CAMERA', 1: 'IMU'}
_SENSOR_NUMBERS = {name: k for k, name in SENSOR_TYPES.items()}
CAMERA = 0
"""The sensor type of a camera: its data ids are image ids."""


@dataclass(frozen=True, eq=False)
class ColmapSensor:
    """A non-reference sensor of a rig.

    Attributes:
        sensor_type: COLMAP sensor type (:data:`CAMERA` = 0, IMU = 1).
        sensor_id: Its id (for a camera, the camera id).
        pose: ``sensor_from_rig`` as (qw, qx, qy, qz, tx, ty, tz), shape (7,), or None:
            not known.
    """

    sensor_type: int
    sensor_id: int
    pose: FloatArray | None


@dataclass(frozen=True, eq=False)
class ColmapRig:
    """A rig: its reference sensor (the rig frame) and the other sensors in file order.

    Attributes:
        ref_type: Sensor type of the reference sensor, or None for a rig without sensors.
        ref_id: Sensor id of the reference sensor (0 without one).
        sensors: The other sensors.
    """

    ref_type: int | None
    ref_id: int
    sensors: tuple[ColmapSensor, ...]

    def sensor_from_rig(self, sensor_type: int, sensor_id: int) -> FloatArray | None:
        """Return a sensor's (qw, qx, qy, qz, tx, ty, tz) (the identity for the reference).

        Returns:
            Shape (7,), or None if the sensor's pose is unknown or it is not on the rig.
        """
        if (sensor_type, sensor_id) == (self.ref_type, self.ref_id):
            return np.array([1.0, 0, 0, 0, 0, 0, 0])
        for s in self.sensors:
            if (s.sensor_type, s.sensor_id) == (sensor_type, sensor_id):
                return s.pose
        return None

    def has_sensor(self, sensor_type: int, sensor_id: int) -> bool:
        """Return True if the sensor is the reference or one of the others."""
        return ((sensor_type, sensor_id) == (self.ref_type, self.ref_id)
                or any((s.sensor_type, s.sensor_id) == (sensor_type, sensor_id)
                       for s in self.sensors))

    def cameras(self) -> list[int]:
        """Return the camera ids of the rig's camera sensors (the reference first)."""
        ids = [self.ref_id] if self.ref_type == CAMERA else []
        return ids + [s.sensor_id for s in self.sensors if s.sensor_type == CAMERA]


@dataclass(frozen=True, eq=False)
class ColmapFrame:
    """A frame: the rig's pose and the data taken at it.

    Attributes:
        rig_id: Its rig.
        qvec: Unit quaternion (w, x, y, z) of ``rig_from_world``'s rotation.
        tvec: ``rig_from_world``'s translation (X_rig = R X + t).
        data_ids: (sensor type, sensor id, data id) rows, shape (D, 3).
    """

    rig_id: int
    qvec: FloatArray
    tvec: FloatArray
    data_ids: IntArray

    def image_ids(self) -> list[tuple[int, int]]:
        """Return the (camera id, image id) of the frame's camera data."""
        rows = self.data_ids[self.data_ids[:, 0] == CAMERA]
        return [(int(c), int(i)) for c, i in rows[:, 1:]]


@dataclass(frozen=True, eq=False)
class ColmapRigs:
    """A model's rigs and frames, keyed by their COLMAP ids, and the files they came from."""

    rigs: dict[int, ColmapRig]
    frames: dict[int, ColmapFrame]
    rigs_path: Path
    frames_path: Path

    def frame_of_image(self) -> dict[int, int]:
        """Return image id -> id of the frame holding it."""
        return {iid: fid for fid, f in self.frames.items() for _, iid in f.image_ids()}

    def has_multi_camera_rig(self) -> bool:
        """Return True if a frame's rig has more than one camera (not independent images)."""
        used = {f.rig_id for f in self.frames.values()}
        return any(len(self.rigs[r].cameras()) > 1 for r in used)


def read_rigs(directory: str | PathLike[str],
              images: dict[int, ColmapImage]) -> ColmapRigs | None:
    """Read a model's rigs and frames (``.bin`` where ``cameras.bin`` is, else ``.txt``).

    Args:
        directory: The model's directory.
        images: The model's images (:func:`~pmba_ros.io.colmap.read_colmap`), which the
            frames are checked against.

    Returns:
        The rigs and frames, or None for a model without the two files (before COLMAP 3.12).

    Raises:
        FormatError: If one of the two files is missing or either is malformed or names
            unknown rigs, sensors or images (the file and line or byte named).
    """
    d = Path(directory)
    ext = '.bin' if (d / 'cameras.bin').is_file() else '.txt'
    rigs_path, frames_path = d / f'rigs{ext}', d / f'frames{ext}'
    present = [p.is_file() for p in (rigs_path, frames_path)]
    if not any(present):
        return None
    if not all(present):
        missing = rigs_path if not present[0] else frames_path
        msg = f'{d}: {missing.name} is missing (a model has both rigs and frames or neither)'
        raise FormatError(msg)
    if ext == '.bin':
        rigs, frames = _read_rigs_bin(rigs_path), _read_frames_bin(frames_path)
    else:
        rigs, frames = _read_rigs_txt(rigs_path), _read_frames_txt(frames_path)
    out = ColmapRigs(rigs, frames, rigs_path, frames_path)
    _check(out, images)
    return out


def _check(model: ColmapRigs, images: dict[int, ColmapImage]) -> None:
    """Refuse frames of unknown rigs, sensors or images, and images in two frames."""
    seen: dict[int, int] = {}
    path = model.frames_path
    for fid, frame in model.frames.items():
        if frame.rig_id not in model.rigs:
            msg = f'{path}: frame {fid} refers to unknown rig {frame.rig_id}'
            raise FormatError(msg)
        rig = model.rigs[frame.rig_id]
        for stype, sid, _ in frame.data_ids.tolist():
            if not rig.has_sensor(stype, sid):
                msg = (f'{path}: frame {fid} has data of sensor {SENSOR_TYPES.get(stype, stype)} '
                       f'{sid}, which is not on its rig {frame.rig_id}')
                raise FormatError(msg)
        for cid, iid in frame.image_ids():
            if iid not in images:
                msg = f'{path}: frame {fid} refers to unknown image {iid}'
                raise FormatError(msg)
            if images[iid].camera_id != cid:
                msg = (f'{path}: frame {fid} has image {iid} as camera {cid}, but the image is '
                       f'of camera {images[iid].camera_id}')
                raise FormatError(msg)
            if iid in seen:
                msg = f'{path}: image {iid} is in frames {seen[iid]} and {fid}'
                raise FormatError(msg)
            seen[iid] = fid


def _sensor_type(path: Path, where: str, token: str) -> int:
    if token not in _SENSOR_NUMBERS:
        msg = f'{path}:{where}: unknown sensor type {token!r} (CAMERA, IMU)'
        raise FormatError(msg)
    return _SENSOR_NUMBERS[token]


def _sensor(rig_id: int, sensor_type: int, sensor_id: int) -> str:
    """Name a rig's sensor in a message, e.g. 'rig 1 camera 2'."""
    return f'rig {rig_id} {SENSOR_TYPES.get(sensor_type, str(sensor_type)).lower()} {sensor_id}'


def _read_rigs_txt(path: Path) -> dict[int, ColmapRig]:
    rigs: dict[int, ColmapRig] = {}
    for n, t in data_lines(path):
        head = integers(path, n, t[:2], 'rig id / number of sensors')
        if head.shape[0] < 2:
            msg = f'{path}:{n}: expected "RIG_ID NUM_SENSORS REF_SENSOR_TYPE REF_SENSOR_ID ..."'
            raise FormatError(msg)
        count, k = int(head[1]), 2
        ref_type, ref_id, sensors = None, 0, []
        try:
            if count > 0:
                ref_type = _sensor_type(path, str(n), t[2])
                ref_id, k = int(t[3]), 4
            for _ in range(max(count - 1, 0)):
                stype, sid, has_pose = _sensor_type(path, str(n), t[k]), int(t[k + 1]), t[k + 2]
                if has_pose not in ('0', '1'):
                    raise ValueError(has_pose)
                pose = None
                if has_pose == '1':
                    pose = numbers(path, n, t[k + 3:k + 10], 'sensor_from_rig')
                    if pose.shape[0] != 7:
                        raise IndexError(k)
                sensors.append(ColmapSensor(stype, sid, pose))
                k += 3 if pose is None else 10
        except (IndexError, ValueError) as err:
            msg = (f'{path}:{n}: expected {count} sensors as "SENSOR_TYPE SENSOR_ID HAS_POSE '
                   '[QW QX QY QZ TX TY TZ]" after the reference sensor')
            raise FormatError(msg) from err
        if k != len(t):
            msg = f'{path}:{n}: {len(t) - k} values after the {count} sensors'
            raise FormatError(msg)
        for sensor in sensors:
            if sensor.pose is not None:
                where = _sensor(int(head[0]), sensor.sensor_type, sensor.sensor_id)
                check_translation(f'{path}:{n}: {where}', sensor.pose[4:])
        check_new_id(f'{path}:{n}', 'rig', int(head[0]), rigs)
        rigs[int(head[0])] = ColmapRig(ref_type, ref_id, tuple(sensors))
    return rigs


def _read_frames_txt(path: Path) -> dict[int, ColmapFrame]:
    frames: dict[int, ColmapFrame] = {}
    for n, t in data_lines(path):
        if len(t) < 10:
            msg = (f'{path}:{n}: expected "FRAME_ID RIG_ID QW QX QY QZ TX TY TZ NUM_DATA_IDS '
                   'DATA_IDS[]"')
            raise FormatError(msg)
        v = numbers(path, n, t[2:9], 'frame pose')
        head = integers(path, n, t[:2] + t[9:10], 'frame id / rig id / number of data ids')
        check_translation(f'{path}:{n}: frame {int(head[0])}', v[4:])
        count = int(head[2])
        rest = t[10:]
        if len(rest) != 3 * count:
            msg = (f'{path}:{n}: {count} data ids need {3 * count} values as "SENSOR_TYPE '
                   f'SENSOR_ID DATA_ID", found {len(rest)}')
            raise FormatError(msg)
        ids = np.empty((count, 3), dtype=np.int64)
        for j in range(count):
            ids[j, 0] = _sensor_type(path, str(n), rest[3 * j])
            ids[j, 1:] = integers(path, n, rest[3 * j + 1:3 * j + 3], 'data id')
        check_new_id(f'{path}:{n}', 'frame', int(head[0]), frames)
        frames[int(head[0])] = ColmapFrame(int(head[1]), v[:4], v[4:], ids)
    return frames


def _read_rigs_bin(path: Path) -> dict[int, ColmapRig]:
    r = BinaryReader(path)
    count = r.count(8, 'rigs')               # id, number of sensors
    rigs: dict[int, ColmapRig] = {}
    for _ in range(count):
        rid, n_sensors = r.take('II')
        ref_type, ref_id, sensors = None, 0, []
        if n_sensors > 0:
            ref_type, ref_id = r.take('iI')
        for _ in range(max(n_sensors - 1, 0)):
            stype, sid, has_pose = r.take('iIB')
            pose = r.array('<f8', 7) if has_pose else None
            if pose is not None:
                check_translation(f'{path}: {_sensor(rid, stype, sid)}', pose[4:])
            sensors.append(ColmapSensor(int(stype), int(sid), pose))
        check_new_id(str(path), 'rig', int(rid), rigs)
        rigs[int(rid)] = ColmapRig(ref_type, int(ref_id), tuple(sensors))
    _check_end(r)
    return rigs


def _read_frames_bin(path: Path) -> dict[int, ColmapFrame]:
    r = BinaryReader(path)
    count = r.count(68, 'frames')            # ids, pose, number of data ids
    frames: dict[int, ColmapFrame] = {}
    for _ in range(count):
        fid, rid = r.take('II')
        pose = r.array('<f8', 7)
        check_translation(f'{path}: frame {fid}', pose[4:])
        (n_data,) = r.take('I')
        rec = r.array('<i4,<u4,<u8', int(n_data))
        ids = np.column_stack([rec['f0'], rec['f1'], rec['f2']]).astype(np.int64)
        check_new_id(str(path), 'frame', int(fid), frames)
        frames[int(fid)] = ColmapFrame(int(rid), pose[:4], pose[4:], ids.reshape(-1, 3))
    _check_end(r)
    return frames


def _check_end(r: BinaryReader) -> None:
    if r.pos != len(r.data):
        msg = f'{r.path}: {len(r.data) - r.pos} bytes after the last record at byte {r.pos}'
        raise FormatError(msg)


def write_rigs(directory: str | PathLike[str], model: ColmapRigs, binary: bool = False) -> None:
    """Write rigs and frames as ``rigs`` and ``frames`` (.txt or .bin) into a directory."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    if binary:
        with (d / 'rigs.bin').open('wb') as fh:
            _write_rigs_bin(fh, model.rigs)
        with (d / 'frames.bin').open('wb') as fh:
            _write_frames_bin(fh, model.frames)
        return
    lines = ['# Rig calib list with one line of data per calib:',
             ('#   RIG_ID, NUM_SENSORS, REF_SENSOR_TYPE, REF_SENSOR_ID, SENSORS[] as '
              '(SENSOR_TYPE, SENSOR_ID, HAS_POSE, [QW, QX, QY, QZ, TX, TY, TZ])'),
             f'# Number of rigs: {len(model.rigs)}']
    for rid, rig in sorted(model.rigs.items()):
        n = len(rig.sensors) + (rig.ref_type is not None)
        words = [str(rid), str(n)]
        if rig.ref_type is not None:
            words += [SENSOR_TYPES[rig.ref_type], str(rig.ref_id)]
        for s in rig.sensors:
            words += [SENSOR_TYPES[s.sensor_type], str(s.sensor_id), str(int(s.pose is not None))]
            words += [] if s.pose is None else [f'{v:.17g}' for v in s.pose]
        lines.append(' '.join(words))
    (d / 'rigs.txt').write_text('\n'.join(lines) + '\n', encoding='utf-8')
    lines = ['# Frame list with one line of data per frame:',
             ('#   FRAME_ID, RIG_ID, RIG_FROM_WORLD[QW, QX, QY, QZ, TX, TY, TZ], NUM_DATA_IDS, '
              'DATA_IDS[] as (SENSOR_TYPE, SENSOR_ID, DATA_ID)'),
             f'# Number of frames: {len(model.frames)}']
    for fid, f in sorted(model.frames.items()):
        pose = ' '.join(f'{v:.17g}' for v in np.concatenate([f.qvec, f.tvec]))
        data = ''.join(f' {SENSOR_TYPES[int(t)]} {int(s)} {int(i)}' for t, s, i in f.data_ids)
        lines.append(f'{fid} {f.rig_id} {pose} {f.data_ids.shape[0]}{data}')
    (d / 'frames.txt').write_text('\n'.join(lines) + '\n', encoding='utf-8')


def _write_rigs_bin(fh: BinaryIO, rigs: dict[int, ColmapRig]) -> None:
    fh.write(struct.pack('<Q', len(rigs)))
    for rid, rig in sorted(rigs.items()):
        fh.write(struct.pack('<II', rid, len(rig.sensors) + (rig.ref_type is not None)))
        if rig.ref_type is not None:
            fh.write(struct.pack('<iI', rig.ref_type, rig.ref_id))
        for s in rig.sensors:
            fh.write(struct.pack('<iIB', s.sensor_type, s.sensor_id, s.pose is not None))
            if s.pose is not None:
                fh.write(np.asarray(s.pose, dtype='<f8').tobytes())


def _write_frames_bin(fh: BinaryIO, frames: dict[int, ColmapFrame]) -> None:
    fh.write(struct.pack('<Q', len(frames)))
    for fid, f in sorted(frames.items()):
        fh.write(struct.pack('<II', fid, f.rig_id))
        fh.write(np.concatenate([f.qvec, f.tvec]).astype('<f8').tobytes())
        fh.write(struct.pack('<I', f.data_ids.shape[0]))
        rec = np.empty(f.data_ids.shape[0], dtype='<i4,<u4,<u8')
        rec['f0'], rec['f1'], rec['f2'] = f.data_ids.T
        fh.write(rec.tobytes())
