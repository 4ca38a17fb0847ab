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
"""Tests of the Bundler v0.3 reader and writer (pmba_ros.io.bundler)."""

from __future__ import annotations

from pathlib import Path
import warnings

import numpy as np
from pmba_ros.core.camera import Intrinsics
from pmba_ros.core.problem import BAProblem, make_problem
from pmba_ros.core.solve import solve, SolveOptions
from pmba_ros.errors import FormatError
from pmba_ros.io import bundler
from pmba_ros.io.bal import read_bal, write_bal
from pmba_ros.sim.scenes import street_scene
import pytest


@pytest.fixture(scope='module')
def centred() -> BAProblem:
    """Return a small street with centred pixels and radial distortion (Bundler's model)."""
    p = street_scene(1, n_cams=6, n_points=120, max_track_length=4, far_fraction=0.0).start
    M = p.n_cams
    f = p.intrinsics.fx
    intr = Intrinsics(f, f, np.zeros(M), np.zeros(M), np.full(M, -0.02), np.full(M, 0.001))
    from pmba_ros.core.camera import project
    pix = project(p.obs.bearings_c, intr, p.obs.cam_idx)
    return make_problem(p.R_wc, p.centers_w, intr, p.obs.cam_idx, p.obs.feat_idx, pix,
                        points_w=p.points_w, n_feats=p.n_feats)


def _bundle_text(problem: BAProblem, unregistered_after: int | None = None) -> str:
    """Write a bundle file by hand (a camera of zeros inserted after camera ``k`` if given)."""
    flip = np.diag([1.0, -1.0, -1.0])
    cams = []
    for k in range(problem.n_cams):
        R = flip @ problem.R_wc[k].T
        t = -R @ problem.centers_w[k]
        i = problem.intrinsics
        cams.append(f'{i.fx[k]:.17g} {i.k1[k]:.17g} {i.k2[k]:.17g}\n'
                    + '\n'.join(' '.join(f'{v:.17g}' for v in row) for row in R)
                    + '\n' + ' '.join(f'{v:.17g}' for v in t))
    file_cam = np.arange(problem.n_cams)
    if unregistered_after is not None:
        cams.insert(unregistered_after + 1, '0 0 0\n0 0 0\n0 0 0\n0 0 0\n0 0 0')
        file_cam[unregistered_after + 1:] += 1
    lines = ['# Bundle file v0.3', f'{len(cams)} {problem.n_feats}', *cams]
    assert problem.points_w is not None
    off = problem.feature_offsets()
    for j in range(problem.n_feats):
        views = []
        for k in range(off[j], off[j + 1]):
            x, y = problem.obs.pixels[k]
            views.append(f'{file_cam[problem.obs.cam_idx[k]]} {7 * k} {x:.17g} {-y:.17g}')
        if unregistered_after is not None and j % 10 == 0:
            views.append(f'{unregistered_after + 1} 3 1.5 -2.5')
        lines += [' '.join(f'{v:.17g}' for v in problem.points_w[j]), '10 20 30',
                  f'{len(views)} ' + ' '.join(views)]
    return '\n'.join(lines) + '\n'


def test_reads_the_hand_written_file_and_round_trips(tmp_path: Path, centred: BAProblem) -> None:
    """Check read -> to_problem gives the problem and write -> read every stored value."""
    src = tmp_path / 'bundle.out'
    src.write_text(_bundle_text(centred))
    model = bundler.read_bundler(src)
    problem, registered = bundler.to_problem(model)
    assert registered.tolist() == list(range(centred.n_cams))
    np.testing.assert_allclose(problem.R_wc, centred.R_wc, atol=1e-12)
    np.testing.assert_allclose(problem.centers_w, centred.centers_w, atol=1e-9)
    np.testing.assert_allclose(problem.obs.pixels, centred.obs.pixels, atol=1e-12)
    np.testing.assert_allclose(problem.obs.bearings_c, centred.obs.bearings_c, atol=1e-12)
    bundler.write_bundler(tmp_path / 'again.out', model)
    again = bundler.read_bundler(tmp_path / 'again.out')
    for field in ('cameras', 'xyz', 'rgb', 'view_offsets', 'view_cam', 'view_key', 'view_xy'):
        np.testing.assert_array_equal(getattr(again, field), getattr(model, field))


def test_conventions_agree_with_the_bal_reader(tmp_path: Path, centred: BAProblem) -> None:
    """The same cameras through a BAL file (Rodrigues vectors) give the same problem."""
    write_bal(tmp_path / 'p.txt', centred)
    via_bal = read_bal(tmp_path / 'p.txt')
    (tmp_path / 'b.out').write_text(_bundle_text(via_bal))
    via_bundler, _ = bundler.to_problem(bundler.read_bundler(tmp_path / 'b.out'))
    np.testing.assert_allclose(via_bundler.R_wc, via_bal.R_wc, atol=1e-12)
    np.testing.assert_allclose(via_bundler.centers_w, via_bal.centers_w, atol=1e-9)
    np.testing.assert_allclose(via_bundler.obs.bearings_c, via_bal.obs.bearings_c, atol=1e-12)


def test_unregistered_cameras_are_left_out_and_written_back(
        tmp_path: Path, centred: BAProblem) -> None:
    """A camera with f = 0 is not in the problem; its views survive a solve and a write."""
    src = tmp_path / 'bundle.out'
    src.write_text(_bundle_text(centred, unregistered_after=2))
    model = bundler.read_bundler(src)
    problem, registered = bundler.to_problem(model)
    assert registered.tolist() == [0, 1, 2, 4, 5, 6]
    assert problem.n_obs == centred.n_obs
    # Six cameras and 2-4-view tracks: with a free gauge the solve crawls along the scale.
    res = solve(problem, SolveOptions(fix_gauge=True))
    assert res.converged and res.final_rms_px < 0.5 * res.initial_rms_px
    out = bundler.updated(model, registered, res.R_wc, res.centers_w, res.problem.feature_ids,
                          res.points_w)
    bundler.write_bundler(tmp_path / 'out.out', out)
    back = bundler.read_bundler(tmp_path / 'out.out')
    np.testing.assert_array_equal(back.cameras[3], 0.0)
    np.testing.assert_array_equal(back.view_cam, model.view_cam)
    refined, _ = bundler.to_problem(back)
    np.testing.assert_allclose(refined.R_wc, res.R_wc, atol=1e-12)
    np.testing.assert_allclose(refined.centers_w, res.centers_w, atol=1e-9)
    # Starting from the written file is at least as good as the solve that wrote it.
    assert solve(refined).final_rms_px <= res.final_rms_px * (1 + 1e-6)


@pytest.mark.parametrize(('text', 'match'), [
    ('# Bundle file v0.2\n1 0\n', 'unsupported header'),
    ('# Bundle file v0.3\n2 0\n1 0 0\n', 'truncated file: 2 cameras'),
    ('# Bundle file v0.3\n1 1\n' + '1 0 0 ' * 5 + '\n0 0 1\n1 2 3\n2 0 0 1 1 5 0 2 2\n',
     'outside 0..0'),
    ('# Bundle file v0.3\n1 1\n' + '1 0 0 ' * 5 + '\n0 0 1\n1 2 3\n3 0 0 1 1\n',
     'point 0: view list'),
    ('# Bundle file v0.3\n1 x\n', r"bad\.out:2: non-numeric token 'x'"),
    # Numbers only Python's float() reads: '1_0' was read as 10.
    ('# Bundle file v0.3\n1 1\n' + '1 0 0 ' * 5 + '\n0 0 1_0\n1 2 3\n1 0 0 1 1\n',
     r"bad\.out:4: non-numeric token '1_0'"),
    ('1 1\n' + '1 0 0 ' * 5 + '\n0 0 1\n1 2 3\n1 0 0 \u0661 1\n',
     r"bad\.out:5: non-numeric token '\u0661'"),
    # Damaged counts: a MemoryError (224 GiB asked for) and ValueErrors before.
    ('# Bundle file v0.3\n1 10000000000\n' + '1 0 0 ' * 5 + '\n',
     'truncated file: 10000000000 points need'),
    ('# Bundle file v0.3\n1 -5\n' + '1 0 0 ' * 5 + '\n', 'negative count'),
    ('# Bundle file v0.3\n-3 2\n', 'negative count'),
    (b'# Bundle file v0.3\n1 1\n\xff\xfe 0 0\n', 'not a text file'),   # a damaged byte
    # Counts that are no whole number: a ValueError / OverflowError before, and a fractional
    # view count misaligned the points after it.
    ('# Bundle file v0.3\nnan 1\n', 'expected "num_cameras num_points"'),
    ('# Bundle file v0.3\n1 inf\n', 'expected "num_cameras num_points"'),
    ('# Bundle file v0.3\n1 1\n' + '1 0 0 ' * 5 + '\n0 0 1\n1 2 3\nnan 0 0 1 1\n',
     'point 0: view count nan is not a whole number'),
    ('# Bundle file v0.3\n1 2\n' + '1 0 0 ' * 5 + '\n0 0 1\n1 2 3\n1.5 0 0 1 1\n'
     '0 0 2\n1 2 3\n1 0 1 1 1\n', 'point 0: view count 1.5 is not a whole number'),
])
def test_malformed_files_are_reported(tmp_path: Path, text: str | bytes, match: str) -> None:
    """Errors name the file and what is wrong."""
    path = tmp_path / 'bad.out'
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(FormatError, match=match) as info:
        bundler.read_bundler(path)
    assert 'bad.out' in str(info.value)


_ONE_CAMERA = '# Bundle file v0.3\n1 1\n' + '1 0 0 ' * 5 + '\n0 0 1\n'


@pytest.mark.parametrize(('point', 'match'), [
    ('nan 20 30\n1 0 7 1 1', r'point 0: colour nan 20 30 is not in 0\.\.255'),
    ('-1 20 30\n1 0 7 1 1', r'point 0: colour -1 20 30 is not in 0\.\.255'),
    ('10 256 30\n1 0 7 1 1', r'point 0: colour 10 256 30 is not in 0\.\.255'),
    ('10 20 1e300\n1 0 7 1 1', r'point 0: colour 10 20 1e\+300 is not in 0\.\.255'),
    ('10 20 30.5\n1 0 7 1 1', r'point 0: colour 10 20 30\.5 is not in 0\.\.255'),
    ('10 20 30\n1 0 nan 1 1', r'point 0: view 0 \(camera 0\): key nan is not a whole number'),
    ('10 20 30\n1 0 1e12 1 1', r'point 0: view 0 \(camera 0\): key 1e\+12 is not a whole'),
    ('10 20 30\n2 0 7 1 1 0 8 1e12 1',
     (r'point 0: view 1 \(camera 0\): image coordinates \(1e\+12, 1\) are not finite or '
      r'beyond 1e\+09')),
    ('10 20 30\n1 0 7 1 nan', r'image coordinates \(1, nan\) are not finite'),
    ('10 20 30\n1 nan 7 1 1', r'a view refers to a camera outside 0\.\.0'),
    ('10 20 30\n1 1e300 7 1 1', r'a view refers to a camera outside 0\.\.0'),
])
def test_absurd_colours_keys_and_pixels_are_refused(tmp_path: Path, point: str,
                                                    match: str) -> None:
    """A colour outside 0..255, a key that is no C int, a pixel beyond 1e9: a FormatError.

    As the COLMAP and BAL readers refuse them; NaN / huge colours and keys were cast to
    arbitrary integers and written back with ``--out``, a pixel of 1e12 was solved.
    """
    path = tmp_path / 'bad.out'
    path.write_text(f'{_ONE_CAMERA}{point}\n')
    with warnings.catch_warnings():
        warnings.simplefilter('error')   # nor a numpy cast warning before the error
        with pytest.raises(FormatError, match=match) as info:
            bundler.read_bundler(path)
    assert 'bad.out' in str(info.value)


_LINES = ['# Bundle file v0.3', '1 1', '500 0 0', '1 0 0', '0 1 0', '0 0 1', '0 0 0', '0 0 -5',
          '10 20 30', '1 0 7 1 1']
"""One camera (lines 3-7: f k1 k2, R, t) and one point (lines 8-10)."""


@pytest.mark.parametrize(('line', 'text', 'match'), [
    (3, '1e200 0 0', r'bad\.out:3: camera 0 has focal length 1e\+200 beyond 1e\+150'),
    (3, '500 0 -1e300', r'bad\.out:3: camera 0 has distortion coefficient -1e\+300 beyond'),
    (7, '0 -1e300 0', r'bad\.out:7: camera 0 has translation coordinate -1e\+300 beyond 1e\+150'),
    (8, '0 0 1e300', r'bad\.out:8: point 0 has coordinate 1e\+300 beyond 1e\+150'),
    (1, '', r'bad\.out:7: point 0 has coordinate 1e\+300 beyond'),   # no header line
])
def test_absurd_cameras_and_points_are_refused_naming_the_line(tmp_path: Path, line: int,
                                                               text: str, match: str) -> None:
    """A focal length, distortion, translation or point coordinate beyond 1e150: a FormatError.

    As BAL's are refused (io.text.MAX_FOCAL, MAX_COORDINATE): they stopped the solve with
    non-finite residuals of a camera index, and the XYZ solve of a translation or point of
    1e300 reported a converged answer.
    """
    lines = list(_LINES)
    lines[line - 1] = text
    if not text:   # the header removed: the point's coordinates one line up
        lines = lines[1:]
        lines[6] = '0 0 1e300'
    path = tmp_path / 'bad.out'
    path.write_text('\n'.join(lines) + '\n')
    with pytest.raises(FormatError, match=match):
        bundler.read_bundler(path)


def test_cameras_and_points_at_the_bounds_are_read(tmp_path: Path) -> None:
    """Magnitudes of 1e150 are read (refused only beyond, as BAL's)."""
    lines = list(_LINES)
    lines[2], lines[6], lines[7] = '1e150 0 1e150', '0 -1e150 0', '0 0 1e150'
    path = tmp_path / 'ok.out'
    path.write_text('\n'.join(lines) + '\n')
    model = bundler.read_bundler(path)
    assert model.cameras[0, 0] == 1e150 and model.xyz[0, 2] == 1e150


def test_whole_colours_keys_and_pixels_at_the_bounds_are_read(tmp_path: Path) -> None:
    """Colours 0 and 255, keys 0 and 2^31 - 1 and a pixel of 1e9 are valid and read."""
    path = tmp_path / 'ok.out'
    path.write_text(f'{_ONE_CAMERA}0 255 0\n2 0 0 -1e9 1 0 2147483647 1 1e9\n')
    model = bundler.read_bundler(path)
    assert model.rgb.tolist() == [[0, 255, 0]]
    assert model.view_key.tolist() == [0, 2 ** 31 - 1]


@pytest.mark.parametrize(('scale_row', 'factor', 'match'), [
    (0, 0.0, 'camera 1 has a rotation that is not a rotation matrix'),   # a row of zeros
    (None, 2.0, 'camera 1 has a rotation that is not a rotation matrix'),  # scaled R
    (2, -1.0, 'camera 1 has a rotation that is not a rotation matrix'),  # mirrored, det -1
])
def test_registered_camera_whose_r_is_not_a_rotation_is_refused(
        tmp_path: Path, centred: BAProblem, scale_row: int | None, factor: float,
        match: str) -> None:
    """Check a damaged R is refused by name, not solved as a wrong camera.

    The solvers never re-orthonormalize R: a zero R used to 'converge' at tens of pixels.
    """
    model = bundler.read_bundler(_write(tmp_path, _bundle_text(centred)))
    cams = model.cameras.copy()
    rows = slice(3, 12) if scale_row is None else slice(3 + 3 * scale_row, 6 + 3 * scale_row)
    cams[1, rows] *= factor
    with pytest.raises(FormatError, match=match):
        bundler.to_problem(bundler.BundlerModel(cams, *_fields_after_cameras(model)))


def test_printed_rotations_are_projected_onto_so3(tmp_path: Path, centred: BAProblem) -> None:
    """R printed to 6 digits (orthonormal to about 1e-6) is read as the nearest rotation."""
    model = bundler.read_bundler(_write(tmp_path, _bundle_text(centred)))
    cams = model.cameras.copy()
    cams[:, 3:12] = np.round(cams[:, 3:12], 6)
    problem, _ = bundler.to_problem(bundler.BundlerModel(cams, *_fields_after_cameras(model)))
    RtR = np.swapaxes(problem.R_wc, 1, 2) @ problem.R_wc
    np.testing.assert_allclose(RtR, np.broadcast_to(np.eye(3), RtR.shape), atol=1e-14)
    np.testing.assert_allclose(problem.R_wc, centred.R_wc, atol=2e-6)


def test_negative_focal_length_is_refused_not_left_out(tmp_path: Path,
                                                       centred: BAProblem) -> None:
    """Check f < 0 (0 marks an unregistered camera) is an error, not a silent drop."""
    model = bundler.read_bundler(_write(tmp_path, _bundle_text(centred)))
    cams = model.cameras.copy()
    cams[2, 0] = -cams[2, 0]
    with pytest.raises(FormatError, match='camera 2 has focal length -'):
        bundler.to_problem(bundler.BundlerModel(cams, *_fields_after_cameras(model)))


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / 'bundle.out'
    path.write_text(text)
    return path


def _fields_after_cameras(model: bundler.BundlerModel) -> tuple[np.ndarray, ...]:
    return (model.xyz, model.rgb, model.view_offsets, model.view_cam, model.view_key,
            model.view_xy)
