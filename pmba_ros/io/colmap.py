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
"""Read and write COLMAP sparse models (``cameras``, ``images``, ``points3D``; text or binary).

A COLMAP image is a pose of this package (one camera per image; intrinsics from its COLMAP
camera), a 3-D point is a feature and every 2-D point with a 3-D point id is an observation.
COLMAP's conventions match this package's (camera x right, y down, z forward; pixels
``u = fx x_d + cx`` with the origin at the image's top-left corner), so only the pose is
converted:

==================  ================================  ======================================
COLMAP              pmba_ros                          note
==================  ================================  ======================================
qvec (w,x,y,z), t   R_wc = R(q)^T, C = -R(q)^T t      world -> camera in the file
SIMPLE_PINHOLE      fx = fy = f, cx, cy
PINHOLE             fx, fy, cx, cy
SIMPLE_RADIAL       fx = fy = f, cx, cy, k1 = k
RADIAL              fx = fy = f, cx, cy, k1, k2
OPENCV              fx, fy, cx, cy, k1, k2            with p1 = p2 = 0 (no tangential)
==================  ================================  ======================================

OPENCV with tangential terms, FULL_OPENCV without rational ones and the fisheye models are
read through OpenCV camera models (:mod:`pmba_ros.io.colmap_cameras`).

Other camera models raise :class:`~pmba_ros.errors.FormatError` naming the model. Writing
updates the poses of the solved images and the positions of the solved points and keeps
everything else (cameras, names, colours, 2-D points, unsolved images and points) as read.
Format reference: COLMAP's ``src/colmap/scene/reconstruction_io.cc`` (text and binary).
Rigs and frames (COLMAP >= 3.12): :mod:`pmba_ros.io.colmap_rigs`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import logging
from pathlib import Path
import struct
from typing import BinaryIO, TYPE_CHECKING

import numpy as np
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.problem import make_problem
from pmba_ros.errors import FormatError, ProblemError
from pmba_ros.io.colmap_cameras import camera_model, through_pinhole
from pmba_ros.io.colmap_errors import track_errors
from pmba_ros.io.colmap_files import (
    BinaryReader,
    check_new_id,
    data_lines,
    integers,
    NAME_ERRORS,
    numbers,
)
from pmba_ros.io.colmap_poses import (
    check_poses,
    check_translation,
    poses_from_colmap,
    poses_to_colmap,
)
from pmba_ros.io.text import check_bounded, MAX_COORDINATE, MAX_FOCAL, MAX_PIXEL

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping
    from os import PathLike

    from pmba_ros._typing import FloatArray, IntArray
    from pmba_ros.core.problem import BAProblem

logger = logging.getLogger(__name__)

__all__ = ['ColmapCamera', 'ColmapImage', 'ColmapModel', 'from_problem', 'is_colmap_model',
           'read_colmap', 'to_problem', 'updated', 'write_colmap']

#: COLMAP model id -> (name, number of parameters).
MODELS: dict[int, tuple[str, int]] = {
    0: ('SIMPLE_PINHOLE', 3), 1: ('PINHOLE', 4), 2: ('SIMPLE_RADIAL', 4), 3: ('RADIAL', 5),
    4: ('OPENCV', 8), 5: ('OPENCV_FISHEYE', 8), 6: ('FULL_OPENCV', 12), 7: ('FOV', 5),
    8: ('SIMPLE_RADIAL_FISHEYE', 4), 9: ('RADIAL_FISHEYE', 5), 10: ('THIN_PRISM_FISHEYE', 12),
}
_MODEL_IDS = {name: (mid, n) for mid, (name, n) in MODELS.items()}
_INVALID_POINT = -1


@dataclass(frozen=True, eq=False)
class ColmapCamera:
    """A COLMAP camera: model name, image size and parameters as in the file."""

    model: str
    width: int
    height: int
    params: FloatArray


@dataclass(frozen=True, eq=False)
class ColmapImage:
    """A COLMAP image: pose (world -> camera), camera id, name and 2-D points.

    Attributes:
        qvec: Unit quaternion (w, x, y, z) of R_cw.
        tvec: Translation t (X_c = R_cw X + t).
        camera_id: Its camera.
        name: Image file name.
        xys: 2-D points (P, 2) in pixels.
        point3d_ids: 3-D point id of each 2-D point, -1 if none, shape (P,).
    """

    qvec: FloatArray
    tvec: FloatArray
    camera_id: int
    name: str
    xys: FloatArray
    point3d_ids: IntArray


@dataclass(frozen=True, eq=False)
class ColmapModel:
    """A sparse model: cameras, images and 3-D points keyed by their COLMAP ids.

    Attributes:
        cameras: Camera id -> camera.
        images: Image id -> image.
        point_ids: 3-D point ids, shape (N,).
        xyz: Positions (N, 3).
        rgb: Colours (N, 3) uint8.
        error: Reprojection errors (N,) as stored.
        tracks: Per point, (image id, 2-D point index) pairs, each shape (L, 2).
    """

    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    point_ids: IntArray
    xyz: FloatArray
    rgb: np.ndarray
    error: FloatArray
    tracks: list[IntArray]


def is_colmap_model(path: str | PathLike[str]) -> bool:
    """Return True if ``path`` is a directory holding a text or binary COLMAP model."""
    p = Path(path)
    return p.is_dir() and any((p / f'cameras{ext}').is_file() for ext in ('.txt', '.bin'))


# ---- reading -----------------------------------------------------------------------------

def read_colmap(directory: str | PathLike[str]) -> ColmapModel:
    """Read a COLMAP model from a directory (``.bin`` files preferred over ``.txt``).

    Raises:
        FormatError: If files are missing or malformed (file and line / record named).
    """
    d = Path(directory)
    if (d / 'cameras.bin').is_file():
        files = [d / f'{n}.bin' for n in ('cameras', 'images', 'points3D')]
        readers = (_read_cameras_bin, _read_images_bin, _read_points_bin)
    else:
        files = [d / f'{n}.txt' for n in ('cameras', 'images', 'points3D')]
        readers = (_read_cameras_txt, _read_images_txt, _read_points_txt)
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        msg = f'{d}: not a COLMAP model, missing {", ".join(missing)}'
        raise FormatError(msg)
    cameras = readers[0](files[0])
    images = readers[1](files[1])
    ids, xyz, rgb, err, tracks = readers[2](files[2], images)
    for iid, img in images.items():
        if img.camera_id not in cameras:
            msg = f'{files[1]}: image {iid} refers to unknown camera {img.camera_id}'
            raise FormatError(msg)
    logger.info('read_colmap %s: %d cameras, %d images, %d points', d, len(cameras),
                len(images), ids.shape[0])
    return ColmapModel(cameras, images, ids, xyz, rgb, err, tracks)


def _camera(path: Path, where: str, model: str, width: int, height: int,
            params: FloatArray) -> ColmapCamera:
    if model not in _MODEL_IDS:
        msg = f'{path}:{where}: unknown camera model {model!r}'
        raise FormatError(msg)
    n = _MODEL_IDS[model][1]
    if params.shape[0] != n:
        msg = f'{path}:{where}: {model} has {n} parameters, found {params.shape[0]}'
        raise FormatError(msg)
    _check_size(f'{path}:{where}', width, height)
    return ColmapCamera(model, width, height, params)


def _check_size(where: str, width: int, height: int) -> None:
    """Raise FormatError naming ``where`` (file, and line or camera) if a size is not positive.

    A camera's image size bounds its pixels and the OpenCV models' undistortion; one of zero
    or below is a damaged record (a negative one even failed to write as a binary model).
    """
    if width <= 0 or height <= 0:
        msg = f'{where}: image size {width} x {height}: expected a positive width and height'
        raise FormatError(msg)


def _check_parameters(where: str, camera: ColmapCamera) -> None:
    """Refuse a camera parameter beyond :data:`~pmba_ros.io.text.MAX_FOCAL`, as BAL's focal length.

    Beyond it the squared pixels overflow: the solve stopped at non-finite residuals of a
    camera index, without the file's camera or line.
    """
    check_bounded(camera.params[None], MAX_FOCAL, f'{camera.model} parameter',
                  lambda _k, _j: where)


def _read_cameras_txt(path: Path) -> dict[int, ColmapCamera]:
    cams: dict[int, ColmapCamera] = {}
    for n, t in data_lines(path):
        if len(t) < 4:
            msg = f'{path}:{n}: expected "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"'
            raise FormatError(msg)
        head = integers(path, n, [t[0], t[2], t[3]], 'camera id / size')
        check_new_id(f'{path}:{n}', 'camera', int(head[0]), cams)
        cams[int(head[0])] = _camera(path, str(n), t[1], int(head[1]), int(head[2]),
                                     numbers(path, n, t[4:], 'camera parameters'))
        _check_parameters(f'{path}:{n}: camera {int(head[0])}', cams[int(head[0])])
    return cams


def _read_images_txt(path: Path) -> dict[int, ColmapImage]:
    with path.open(encoding='utf-8', errors=NAME_ERRORS) as fh:
        lines = [(n, line.split()) for n, line in enumerate(fh, 1)
                 if not line.lstrip().startswith('#')]
    images: dict[int, ColmapImage] = {}
    k = 0
    while k < len(lines):
        n, head = lines[k]
        if not head:  # blank lines between images
            k += 1
            continue
        # The 2-D points line follows the header; it is empty (or missing at the end of
        # the file) for an image without points.
        n2, pts = lines[k + 1] if k + 1 < len(lines) else (n + 1, [])
        k += 2
        if len(head) < 10:
            msg = f'{path}:{n}: expected "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"'
            raise FormatError(msg)
        v = numbers(path, n, head[1:8], 'image pose')
        ids = integers(path, n, [head[0], head[8]], 'image / camera id')
        if len(pts) % 3:
            msg = f'{path}:{n2}: 2-D points must be "X Y POINT3D_ID" triples'
            raise FormatError(msg)
        xys = numbers(path, n2, pts[0::3] + pts[1::3], 'image points').reshape(2, -1).T
        check_new_id(f'{path}:{n}', 'image', int(ids[0]), images)
        check_translation(f'{path}:{n}: image {int(ids[0])}', v[4:])
        images[int(ids[0])] = ColmapImage(v[:4], v[4:], int(ids[1]), ' '.join(head[9:]), xys,
                                          integers(path, n2, pts[2::3], 'image points'))
    return images


def _read_points_txt(path: Path, images: Mapping[int, ColmapImage],
                     ) -> tuple[IntArray, FloatArray, np.ndarray, FloatArray, list[IntArray]]:
    ids, xyz, rgb, err, tracks, lines = [], [], [], [], [], []
    seen: dict[int, None] = {}
    for n, t in data_lines(path):
        if len(t) < 8 or (len(t) - 8) % 2:
            msg = (f'{path}:{n}: expected "POINT3D_ID X Y Z R G B ERROR" and (IMAGE_ID, '
                   'POINT2D_IDX) pairs')
            raise FormatError(msg)
        v = numbers(path, n, t[1:4] + t[7:8], 'point')
        whole = integers(path, n, t[:1] + t[4:7] + t[8:], 'point')
        if np.any((whole[1:4] < 0) | (whole[1:4] > 255)):
            msg = f'{path}:{n}: colour {" ".join(t[4:7])} is not in 0..255'
            raise FormatError(msg)
        check_new_id(f'{path}:{n}', '3-D point', int(whole[0]), seen)
        seen[int(whole[0])] = None
        track = whole[4:].reshape(-1, 2)
        _check_track(f'{path}:{n}', int(whole[0]), track, images)
        ids.append(int(whole[0]))
        xyz.append(v[:3])
        rgb.append(whole[1:4])
        err.append(v[3])
        tracks.append(track)
        lines.append(n)
    xyz_array = np.array(xyz, dtype=float).reshape(-1, 3)
    _check_points(xyz_array, lambda k: f'{path}:{lines[k]}: 3-D point {ids[k]}')
    return (np.array(ids, dtype=np.int64), xyz_array,
            np.array(rgb, dtype=np.uint8).reshape(-1, 3), np.array(err, dtype=float), tracks)


def _read_cameras_bin(path: Path) -> dict[int, ColmapCamera]:
    r = BinaryReader(path)
    count = r.count(24, 'cameras')        # id, model, width, height
    cams: dict[int, ColmapCamera] = {}
    for _ in range(count):
        cid, mid, w, h = r.take('iiQQ')
        if mid not in MODELS:
            msg = f'{path}: camera {cid} has unknown model id {mid}'
            raise FormatError(msg)
        name, n = MODELS[int(mid)]
        check_new_id(str(path), 'camera', int(cid), cams)
        _check_size(f'{path}: camera {cid}', int(w), int(h))
        cams[int(cid)] = ColmapCamera(name, int(w), int(h),
                                      r.array('<f8', n))
        _check_parameters(f'{path}: camera {cid}', cams[int(cid)])
    return cams


def _read_images_bin(path: Path) -> dict[int, ColmapImage]:
    r = BinaryReader(path)
    count = r.count(73, 'images')         # id, pose, camera id, name's NUL, point count
    images: dict[int, ColmapImage] = {}
    for _ in range(count):
        (iid,) = r.take('i')
        pose = r.array('<f8', 7)
        (cid,) = r.take('i')
        name = r.string()
        (n_pts,) = r.take('Q')
        rec = r.array('<f8,<f8,<i8', int(n_pts))
        xys = np.stack([rec['f0'], rec['f1']], axis=1)
        check_new_id(str(path), 'image', int(iid), images)
        check_translation(f'{path}: image {iid}', pose[4:])
        images[int(iid)] = ColmapImage(pose[:4], pose[4:], int(cid),
                                       name, xys, rec['f2'].astype(np.int64))
    return images


def _read_points_bin(path: Path, images: Mapping[int, ColmapImage],
                     ) -> tuple[IntArray, FloatArray, np.ndarray, FloatArray, list[IntArray]]:
    r = BinaryReader(path)
    n = r.count(51, 'points')             # id, xyz, rgb, error, track length
    ids = np.empty(n, dtype=np.int64)
    xyz = np.empty((n, 3))
    rgb = np.empty((n, 3), dtype=np.uint8)
    err = np.empty(n)
    tracks = []
    for k in range(n):
        (pid,) = r.take('q')   # uint64 in the file, as images.bin's references are read
        ids[k] = pid
        xyz[k] = r.array('<f8', 3)
        rgb[k] = r.array('u1', 3)
        (err[k], length) = r.take('dQ')
        tracks.append(r.array('<i4', 2 * int(length)).astype(np.int64).reshape(-1, 2))
        _check_track(str(path), int(pid), tracks[-1], images)
    if np.unique(ids).size < n:
        _, first = np.unique(ids, return_index=True)
        repeated = int(ids[np.setdiff1d(np.arange(n), first).min()])
        msg = f'{path}: 3-D point id {repeated} appears twice'
        raise FormatError(msg)
    _check_points(xyz, lambda k: f'{path}: 3-D point {ids[k]}')
    return ids, xyz, rgb, err, tracks


def _check_points(xyz: FloatArray, where: Callable[[int], str]) -> None:
    """Refuse a 3-D point coordinate beyond :data:`~pmba_ros.io.text.MAX_COORDINATE`.

    ``where(k)`` names the file, line and id of point k. The XYZ solve of a point at 1e300
    reported a converged answer with the point where it was.
    """
    check_bounded(xyz, MAX_COORDINATE, 'coordinate', lambda k, _j: where(k))


def _check_track(where: str, point_id: int, track: IntArray,
                 images: Mapping[int, ColmapImage]) -> None:
    """Raise FormatError naming ``where`` if a track element names no image or 2-D point.

    The solve takes its observations from the images, not from the tracks, so a damaged
    track went unnoticed and was written back with ``--out`` into a model COLMAP refuses.
    """
    for image_id, index in track.tolist():
        if image_id not in images:
            msg = (f'{where}: the track of 3-D point {point_id} refers to unknown image '
                   f'{image_id}')
            raise FormatError(msg)
        n_points = images[image_id].xys.shape[0]
        if not 0 <= index < n_points:
            msg = (f'{where}: the track of 3-D point {point_id} refers to 2-D point {index} of '
                   f'image {image_id}, which has {n_points} 2-D points')
            raise FormatError(msg)


# ---- conversion --------------------------------------------------------------------------

def to_problem(model: ColmapModel) -> tuple[BAProblem, IntArray]:
    """Return the BA problem of a model and the COLMAP image id of each of its cameras.

    Cameras are the model's images in ascending id order; ``feature_ids`` are the 3-D point
    ids; points seen by fewer than two images are dropped (counted in ``dropped``).

    Raises:
        FormatError: On unsupported camera models or inconsistent tracks.
    """
    image_ids = sorted(model.images)
    if not image_ids:
        msg = 'COLMAP model has no images'
        raise FormatError(msg)
    cam_of = {iid: k for k, iid in enumerate(image_ids)}
    used = sorted({model.images[i].camera_id for i in image_ids})
    cameras = {cid: camera_model(model.cameras[cid], cid) for cid in used}
    for cid, ((fx, fy, cx, cy, *_), _) in cameras.items():
        if not (fx > 0 and fy > 0 and np.isfinite([fx, fy, cx, cy]).all()):
            msg = (f'COLMAP camera {cid} ({model.cameras[cid].model}): focal lengths {fx:g}, '
                   f'{fy:g}, centre {cx:g}, {cy:g}; expected positive focal lengths and finite '
                   'values')
            raise FormatError(msg)
    rows, models = zip(*(cameras[model.images[i].camera_id] for i in image_ids), strict=True)
    a = np.array(rows, dtype=float).reshape(-1, 6)
    intr = Intrinsics(*(a[:, i].copy() for i in range(6)))
    q = np.array([model.images[i].qvec for i in image_ids])
    t = np.array([model.images[i].tvec for i in image_ids])
    check_poses(q, t, [f'image {i}' for i in image_ids])
    R_wc, centers = poses_from_colmap(q, t)
    feat_of = {int(pid): j for j, pid in enumerate(model.point_ids)}
    cam_idx, feat_idx, pix = [], [], []
    for iid in image_ids:
        img = model.images[iid]
        has = img.point3d_ids != _INVALID_POINT
        pids = img.point3d_ids[has]
        try:
            feats = [feat_of[int(p)] for p in pids]
        except KeyError as err:
            msg = f'COLMAP image {iid} refers to unknown 3-D point {err.args[0]}'
            raise FormatError(msg) from err
        xy = img.xys[has]
        bad = ~(np.abs(xy) <= MAX_PIXEL).all(axis=1)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            msg = (f'COLMAP image {iid}: 2-D point of 3-D point {int(pids[k])} at '
                   f'({xy[k, 0]:g}, {xy[k, 1]:g}) px: not a pixel')
            raise FormatError(msg)
        cam_idx.append(np.full(len(feats), cam_of[iid], dtype=np.int64))
        feat_idx.append(np.array(feats, dtype=np.int64))
        pix.append(xy)
    cams = np.concatenate(cam_idx)
    pixels = np.concatenate(pix).reshape(-1, 2)
    pixel_jac = None
    if any(m is not None for m in models):
        pixels, pixel_jac = through_pinhole(pixels, cams, intr, list(models))
    try:
        problem = make_problem(R_wc, centers, intr, cams, np.concatenate(feat_idx), pixels,
                               points_w=model.xyz, n_feats=model.point_ids.shape[0],
                               feature_ids=model.point_ids, pixel_jac=pixel_jac)
    except ProblemError as err:
        msg = f'COLMAP model: {err}'
        raise FormatError(msg) from err
    return problem, np.array(image_ids, dtype=np.int64)


def updated(model: ColmapModel, image_ids: IntArray, R_wc: FloatArray, centers_w: FloatArray,
            point_ids: IntArray, points_w: FloatArray) -> ColmapModel:
    """Return the model with new poses for ``image_ids`` and positions for ``point_ids``.

    Non-finite points (PMBA points at infinity, which COLMAP cannot store) keep their stored
    position. The points' reprojection errors are computed again for the new model.
    """
    q, t = poses_to_colmap(R_wc, centers_w)
    images = dict(model.images)
    for k, iid in enumerate(np.asarray(image_ids).tolist()):
        images[iid] = replace(images[iid], qvec=q[k], tvec=t[k])
    xyz = model.xyz.copy()
    index = {int(pid): j for j, pid in enumerate(model.point_ids)}
    rows = np.array([index[int(p)] for p in point_ids], dtype=np.int64)
    finite = np.all(np.isfinite(points_w), axis=1)
    xyz[rows[finite]] = np.asarray(points_w)[finite]
    refined = replace(model, images=images, xyz=xyz)
    return replace(refined, error=track_errors(refined))


# ---- writing -----------------------------------------------------------------------------

def write_colmap(directory: str | PathLike[str], model: ColmapModel,
                 binary: bool = False) -> None:
    """Write a model as ``cameras``, ``images``, ``points3D`` (.txt or .bin) into a directory."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    if binary:
        with (d / 'cameras.bin').open('wb') as fh:
            _write_cameras_bin(fh, model)
        with (d / 'images.bin').open('wb') as fh:
            _write_images_bin(fh, model)
        with (d / 'points3D.bin').open('wb') as fh:
            _write_points_bin(fh, model)
        return
    lines = ['# Camera list with one line of data per camera:',
             '#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]',
             f'# Number of cameras: {len(model.cameras)}']
    lines += [f'{cid} {c.model} {c.width} {c.height} ' + ' '.join(f'{v:.17g}' for v in c.params)
              for cid, c in sorted(model.cameras.items())]
    (d / 'cameras.txt').write_text('\n'.join(lines) + '\n', encoding='utf-8')
    lines = ['# Image list with two lines of data per image:',
             '#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME',
             '#   POINTS2D[] as (X, Y, POINT3D_ID)',
             f'# Number of images: {len(model.images)}']
    for iid, img in sorted(model.images.items()):
        pose = ' '.join(f'{v:.17g}' for v in np.concatenate([img.qvec, img.tvec]))
        lines.append(f'{iid} {pose} {img.camera_id} {img.name}')
        lines.append(' '.join(f'{x:.17g} {y:.17g} {int(p)}'
                              for (x, y), p in zip(img.xys, img.point3d_ids, strict=True)))
    (d / 'images.txt').write_text('\n'.join(lines) + '\n', encoding='utf-8', errors=NAME_ERRORS)
    lines = ['# 3D point list with one line of data per point:',
             '#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)',
             f'# Number of points: {model.point_ids.shape[0]}']
    for k, pid in enumerate(model.point_ids.tolist()):
        x, y, z = model.xyz[k]
        r, g, b = model.rgb[k].tolist()
        track = ' '.join(str(int(v)) for v in model.tracks[k].ravel())
        lines.append(f'{pid} {x:.17g} {y:.17g} {z:.17g} {r} {g} {b} {model.error[k]:.17g} '
                     f'{track}')
    (d / 'points3D.txt').write_text('\n'.join(lines) + '\n', encoding='utf-8')


def _write_cameras_bin(fh: BinaryIO, model: ColmapModel) -> None:
    fh.write(struct.pack('<Q', len(model.cameras)))
    for cid, c in sorted(model.cameras.items()):
        fh.write(struct.pack('<iiQQ', cid, _MODEL_IDS[c.model][0], c.width, c.height))
        fh.write(np.asarray(c.params, dtype='<f8').tobytes())


def _write_images_bin(fh: BinaryIO, model: ColmapModel) -> None:
    fh.write(struct.pack('<Q', len(model.images)))
    for iid, img in sorted(model.images.items()):
        fh.write(struct.pack('<i', iid))
        fh.write(np.concatenate([img.qvec, img.tvec]).astype('<f8').tobytes())
        fh.write(struct.pack('<i', img.camera_id))
        fh.write(img.name.encode('utf-8', errors=NAME_ERRORS) + b'\0')
        fh.write(struct.pack('<Q', img.xys.shape[0]))
        rec = np.empty(img.xys.shape[0], dtype='<f8,<f8,<i8')
        rec['f0'], rec['f1'], rec['f2'] = img.xys[:, 0], img.xys[:, 1], img.point3d_ids
        fh.write(rec.tobytes())


def _write_points_bin(fh: BinaryIO, model: ColmapModel) -> None:
    fh.write(struct.pack('<Q', model.point_ids.shape[0]))
    for k, pid in enumerate(model.point_ids.tolist()):
        fh.write(struct.pack('<Q', pid))
        fh.write(model.xyz[k].astype('<f8').tobytes())
        fh.write(model.rgb[k].astype('u1').tobytes())
        fh.write(struct.pack('<dQ', model.error[k], model.tracks[k].shape[0]))
        fh.write(model.tracks[k].astype('<i4').tobytes())


def from_problem(problem: BAProblem, points_w: FloatArray | None = None,
                 image_size: tuple[int, int] | None = None) -> ColmapModel:
    """Return a COLMAP model of a problem: one camera and one image per pose.

    Cameras are PINHOLE, or RADIAL when the pose has distortion and fx = fy (OPENCV
    otherwise); the image size defaults to twice the principal point. Images get ids 1..M
    and names ``image_000001.png``...; points keep ``feature_ids`` as ids, colour grey.

    Raises:
        ProblemError: If the problem has no points and none are given.
    """
    pts = problem.points_w if points_w is None else np.asarray(points_w, dtype=float)
    if pts is None:
        msg = 'from_problem: the problem has no points; pass points_w'
        raise ProblemError(msg)
    intr = problem.intrinsics
    cameras = {}
    for k in range(problem.n_cams):
        # At least one pixel: a principal point at the origin (BAL's) would give a size of
        # zero, which the reader refuses.
        w, h = image_size or (max(1, round(2 * intr.cx[k])), max(1, round(2 * intr.cy[k])))
        fx, fy, cx, cy, k1, k2 = (float(getattr(intr, f)[k])
                                  for f in ('fx', 'fy', 'cx', 'cy', 'k1', 'k2'))
        if k1 == 0.0 and k2 == 0.0:
            cam = ColmapCamera('PINHOLE', w, h, np.array([fx, fy, cx, cy]))
        elif fx == fy:
            cam = ColmapCamera('RADIAL', w, h, np.array([fx, cx, cy, k1, k2]))
        else:
            cam = ColmapCamera('OPENCV', w, h, np.array([fx, fy, cx, cy, k1, k2, 0.0, 0.0]))
        cameras[k + 1] = cam
    q, t = poses_to_colmap(problem.R_wc, problem.centers_w)
    obs = problem.obs
    ids = np.asarray(problem.feature_ids, dtype=np.int64)
    images = {}
    tracks: list[list[tuple[int, int]]] = [[] for _ in range(problem.n_feats)]
    for k in range(problem.n_cams):
        mine = np.flatnonzero(obs.cam_idx == k)
        for idx, j in enumerate(obs.feat_idx[mine].tolist()):
            tracks[j].append((k + 1, idx))
        images[k + 1] = ColmapImage(q[k], t[k], k + 1, f'image_{k + 1:06d}.png',
                                    obs.pixels[mine].copy(), ids[obs.feat_idx[mine]])
    return ColmapModel(cameras, images, ids, np.array(pts, dtype=float),
                       np.full((problem.n_feats, 3), 128, dtype=np.uint8),
                       np.zeros(problem.n_feats),
                       [np.array(t_, dtype=np.int64).reshape(-1, 2) for t_ in tracks])
