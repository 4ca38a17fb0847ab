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
"""Tests of pmba_ros.io.bal: conventions, reprojection statistics, round trips, malformed files."""

from __future__ import annotations

import bz2
from collections.abc import Callable
import gzip
import lzma
from pathlib import Path
import re
import time

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core import so3
from pmba_ros.core.camera import Intrinsics, project
from pmba_ros.core.problem import BAProblem, make_problem
from pmba_ros.errors import FormatError, ProblemError
from pmba_ros.io.bal import read_bal, write_bal
from pmba_ros.io.text import detect_problem_format
import pytest
from scipy.spatial.transform import Rotation  # type: ignore[import-untyped]

from ..conftest import SHARED_DATA

BAL_DIR = SHARED_DATA / 'bal'
needs_data = pytest.mark.skipif(not BAL_DIR.is_dir(), reason='shared/data/bal not available')


def reprojection_errors_px(problem: BAProblem, points_w: FloatArray | None = None) -> FloatArray:
    """Return |project(R_wc^T (X - C)) - pixel| per observation (px)."""
    pts = problem.points_w if points_w is None else points_w
    assert pts is not None
    obs = problem.obs
    h_c = np.einsum('kji,kj->ki', problem.R_wc[obs.cam_idx],
                    pts[obs.feat_idx] - problem.centers_w[obs.cam_idx])
    err: FloatArray = np.linalg.norm(
        project(h_c, problem.intrinsics, obs.cam_idx) - obs.pixels, axis=1)
    return err


@needs_data
@pytest.mark.parametrize(('name', 'counts', 'median_px', 'rms_px'), [
    ('problem-49-7776-pre.txt', (49, 7776, 31843), 1.48, 7.31),
    ('bal-ladybug-problem-49-7776-pre-shrink-1800.txt', (49, 1800, 10863), 2.18, 6.57),
    ('problem-21-11315-pre.txt', (21, 11315, 36455), 2.98, 15.56),
    ('dubrovnik-3-7-pre.txt', (3, 7, 19), 11.25, 17.06),
    ('dubrovnik-3-7-18-pre.txt', (3, 7, 18), 11.40, 17.49),
])
def test_read_bal_reproduces_sources_reprojection_stats(
        name: str, counts: tuple[int, int, int], median_px: float, rms_px: float) -> None:
    """Our camera model on the converted poses gives the median / RMS quoted in SOURCES.md."""
    problem = read_bal(BAL_DIR / name)
    assert (problem.n_cams, problem.n_feats, problem.n_obs) == counts
    err = reprojection_errors_px(problem)
    assert np.median(err) == pytest.approx(median_px, abs=0.005)
    assert np.sqrt(np.mean(err**2)) == pytest.approx(rms_px, abs=0.005)


@needs_data
def test_read_bal_ladybug_is_fast_and_has_few_points_behind() -> None:
    """The 1.8 MB Ladybug file reads in well under a second; 0.1 % of obs are behind."""
    t0 = time.perf_counter()
    problem = read_bal(BAL_DIR / 'problem-49-7776-pre.txt')
    assert time.perf_counter() - t0 < 1.0
    assert problem.points_w is not None
    obs = problem.obs
    depth = np.einsum('ki,ki->k', problem.R_wc[obs.cam_idx][:, :, 2],
                      problem.points_w[obs.feat_idx] - problem.centers_w[obs.cam_idx])
    assert 0.0005 < np.mean(depth <= 0) < 0.002
    assert np.all((problem.intrinsics.fx > 390) & (problem.intrinsics.fx < 415))


@needs_data
def test_read_bal_converts_to_optical_frame_convention() -> None:
    """R_wc = (diag(1,-1,-1) R_bal)^T, C = -R_bal^T t, pixel (x, -y), fx = fy = f."""
    path = BAL_DIR / 'dubrovnik-3-7-pre.txt'
    problem = read_bal(path)
    values = np.array(path.read_text().split(), dtype=float)
    cams = values[3 + 4 * 19:3 + 4 * 19 + 27].reshape(3, 9)
    R_bal = Rotation.from_rotvec(cams[:, :3]).as_matrix()
    np.testing.assert_allclose(problem.R_wc,
                               np.swapaxes(np.diag([1.0, -1.0, -1.0]) @ R_bal, 1, 2), atol=1e-12)
    np.testing.assert_allclose(problem.centers_w,
                               -np.einsum('mji,mj->mi', R_bal, cams[:, 3:6]), atol=1e-9)
    np.testing.assert_array_equal(problem.intrinsics.fx, cams[:, 6])
    np.testing.assert_array_equal(problem.intrinsics.fy, cams[:, 6])
    np.testing.assert_array_equal(problem.intrinsics.cx, 0.0)
    np.testing.assert_array_equal(problem.intrinsics.k2, cams[:, 8])
    # First observation "0 0 -3.859900e+02 3.871200e+02" (feature 0, camera 0).
    assert (problem.obs.cam_idx[0], problem.obs.feat_idx[0]) == (0, 0)
    np.testing.assert_allclose(problem.obs.pixels[0], [-385.99, -387.12])
    np.testing.assert_array_equal(problem.feature_ids, np.arange(7))


@needs_data
def test_read_bal_single_observation_file_has_no_features() -> None:
    """dubrovnik-1-1 has one observation: its point is dropped (needs two cameras)."""
    problem = read_bal(BAL_DIR / 'dubrovnik-1-1-pre.txt')
    assert (problem.n_cams, problem.n_feats, problem.n_obs) == (1, 0, 0)
    assert problem.dropped['single_observation_features'] == 1


@needs_data
def test_write_read_round_trip_of_bal_file(tmp_path: Path) -> None:
    """A read -> write -> read cycle keeps poses, intrinsics, observations and points."""
    first = read_bal(BAL_DIR / 'bal-ladybug-problem-49-7776-pre-shrink-1800.txt')
    out = tmp_path / 'round.txt'
    write_bal(out, first)
    second = read_bal(out)
    assert (second.n_cams, second.n_feats, second.n_obs) == (first.n_cams, first.n_feats,
                                                             first.n_obs)
    np.testing.assert_allclose(second.R_wc, first.R_wc, atol=1e-12)
    np.testing.assert_allclose(second.centers_w, first.centers_w, rtol=1e-12, atol=1e-12)
    assert first.points_w is not None and second.points_w is not None
    np.testing.assert_array_equal(second.points_w, first.points_w)
    np.testing.assert_array_equal(second.obs.pixels, first.obs.pixels)
    np.testing.assert_array_equal(second.obs.cam_idx, first.obs.cam_idx)
    np.testing.assert_array_equal(second.intrinsics.k1, first.intrinsics.k1)


def _synthetic_problem(rng: np.random.Generator) -> tuple[BAProblem, FloatArray]:
    """Return a 3-camera problem with fx != fy, an off-centre principal point, distortion."""
    n_cams, n_pts = 3, 12
    R_wc = so3.exp(rng.normal(0.0, 0.1, (n_cams, 3)))
    centers = rng.normal(0.0, 0.5, (n_cams, 3))
    points = rng.uniform([-2, -2, 6], [2, 2, 10], (n_pts, 3))
    intr = Intrinsics(np.array([500.0, 510, 520]), np.array([530.0, 505, 520]),
                      np.array([320.0, 300, 310]), np.array([240.0, 250, 200]),
                      np.array([0.01, -0.02, 0.0]), np.array([-0.001, 0.002, 0.0]))
    cam_idx = np.repeat(np.arange(n_cams), n_pts)
    feat_idx = np.tile(np.arange(n_pts), n_cams)
    h_c = np.einsum('kji,kj->ki', R_wc[cam_idx], points[feat_idx] - centers[cam_idx])
    pixels = project(h_c, intr, cam_idx)
    return make_problem(R_wc, centers, intr, cam_idx, feat_idx, pixels), points


def test_write_bal_rescales_pixels_for_general_intrinsics(tmp_path: Path) -> None:
    """Intrinsics with fy != fx and cx, cy != 0 are written exactly (zero reprojection)."""
    problem, points = _synthetic_problem(np.random.default_rng(3))
    out = tmp_path / 'synthetic.txt'
    write_bal(out, problem, points_w=points)
    back = read_bal(out)
    np.testing.assert_allclose(back.R_wc, problem.R_wc, atol=1e-12)
    np.testing.assert_allclose(back.centers_w, problem.centers_w, atol=1e-12)
    np.testing.assert_array_equal(back.intrinsics.fx, problem.intrinsics.fx)
    assert np.max(reprojection_errors_px(back)) < 1e-8
    np.testing.assert_allclose(back.obs.bearings_c, problem.obs.bearings_c, atol=1e-12)


def test_write_bal_without_points_raises(tmp_path: Path) -> None:
    """A problem without points needs explicit points_w."""
    problem, _ = _synthetic_problem(np.random.default_rng(0))
    with pytest.raises(ProblemError, match='no points'):
        write_bal(tmp_path / 'x.txt', problem)
    with pytest.raises(ProblemError, match='expected R_wc'):
        write_bal(tmp_path / 'x.txt', problem, points_w=np.zeros((2, 3)))


def _valid_bal_lines() -> list[str]:
    """Return the lines of a 2-camera, 2-point, 4-observation BAL file (values from line 6)."""
    lines = ['2 2 4', '0 0 1.0 2.0', '1 0 -1.0 2.5', '0 1 3.0 -1.0', '1 1 2.0 0.5']
    cam = ['0.01', '0.02', '0.03', '0.1', '0.2', '-5.0', '500.0', '0.0', '0.0']
    lines += cam + cam
    lines += ['0.1', '0.2', '1.0', '-0.3', '0.4', '2.0']
    return lines


def test_valid_small_bal_file_reads(tmp_path: Path) -> None:
    """The fixture used by the malformed-file tests is itself valid."""
    path = tmp_path / 'ok.txt'
    path.write_text('\n'.join(_valid_bal_lines()) + '\n')
    problem = read_bal(path)
    assert (problem.n_cams, problem.n_feats, problem.n_obs) == (2, 2, 4)


def _replace(lines: list[str], line_no: int, text: str | None) -> list[str]:
    """Return ``lines`` with 1-based line ``line_no`` replaced (or removed when None)."""
    out = list(lines)
    if text is None:
        del out[line_no - 1]
    else:
        out[line_no - 1] = text
    return out


@pytest.mark.parametrize(('mutate', 'line', 'match'), [
    (lambda ls: _replace(ls, 1, '2 2'), 1, 'bad header'),
    (lambda ls: _replace(ls, 1, '2 x 4'), 1, 'bad header'),
    (lambda ls: _replace(ls, 3, '1 0 -1.0'), 3, 'observation line has 3 values'),
    (lambda ls: _replace(ls, 4, '0 1 3.0 abc'), 4, "non-numeric token 'abc'"),
    (lambda ls: _replace(ls, 2, '5 0 1.0 2.0'), 2, 'camera index 5 is not an integer'),
    (lambda ls: _replace(ls, 5, '1 0.5 2.0 0.5'), 5, 'point index 0.5 is not an integer'),
    (lambda ls: _replace(ls, 5, '1 -1 2.0 0.5'), 5, 'point index -1'),
    (lambda ls: _replace(ls, 3, '1 0 nan 2.5'), 3, 'non-finite pixel'),
    (lambda ls: _replace(ls, 12, 'oops'), 12, "non-numeric token 'oops'"),
    # Numbers only Python's float() reads ('1_000', other scripts' digits): an observation
    # line was refused without its line, a parameter or a header count read.
    (lambda ls: _replace(ls, 3, '1 0 -1_0 2.5'), 3, "non-numeric token '-1_0'"),
    (lambda ls: _replace(ls, 4, '0 1 \uff13.0 -1.0'), 4, "non-numeric token '\uff13.0'"),
    (lambda ls: _replace(ls, 21, '5_00.0'), 21, "non-numeric token '5_00.0'"),
    (lambda ls: _replace(ls, 1, '2 2 0_4'), 1, 'bad header'),
    (lambda ls: _replace(ls, 21, '-500.0'), 21, 'camera 1 has non-positive focal length'),
    (lambda ls: _replace(ls, 25, 'inf'), 25, 'non-finite parameter'),
    (lambda ls: _replace(ls, 19, '-1e300'), 19,
     r'camera 1 has translation coordinate -1e\+300 beyond 1e\+150'),
    (lambda ls: _replace(ls, 16, '1e200'), 16,
     r'camera 1 has rotation vector coordinate 1e\+200 beyond 1e\+150'),
    (lambda ls: _replace(ls, 21, '1e200'), 21, r'camera 1 has focal length 1e\+200 beyond'),
    (lambda ls: _replace(ls, 22, '1e300'), 22,
     r'camera 1 has distortion coefficient 1e\+300 beyond 1e\+150'),
    (lambda ls: _replace(ls, 25, '-1e300'), 25, r'point 0 has coordinate -1e\+300 beyond 1e\+150'),
    (lambda ls: ls[:-1], 28, 'truncated file: expected 24 camera and point values'),
    (lambda ls: [*ls, '7.0', '8.0'], 30, 'unexpected extra values'),
    (lambda ls: ls[:3], 3, 'truncated file: header announces 4 observation lines'),
])
def test_malformed_bal_raises_format_error_with_line(
        tmp_path: Path, mutate: object, line: int, match: str) -> None:
    """Malformed files raise FormatError naming the file, the line and the problem."""
    path = tmp_path / 'broken.txt'
    assert callable(mutate)
    path.write_text('\n'.join(mutate(_valid_bal_lines())) + '\n')
    with pytest.raises(FormatError, match=f'{re.escape(str(path))}:{line}: .*{match}'):
        read_bal(path)


def test_blank_lines_do_not_shift_line_numbers(tmp_path: Path) -> None:
    """Blank lines are skipped, and reported line numbers are the file's own."""
    lines = _valid_bal_lines()
    lines = [lines[0], '', *lines[1:3], '', '1 0 3.0', *lines[4:]]
    path = tmp_path / 'blank.txt'
    path.write_text('\n'.join(lines) + '\n')
    with pytest.raises(FormatError, match=r':6: observation line has 3 values'):
        read_bal(path)


@pytest.mark.parametrize('compress', [bz2.compress, gzip.compress, lzma.compress])
def test_compressed_bal_file_reads_as_the_plain_one(
        tmp_path: Path, compress: Callable[[bytes], bytes]) -> None:
    """A problem as the BAL site publishes it (``.bz2``), or gzip / xz, is read decompressed.

    The compression is told by the content: a name without its suffix reads as well.
    """
    text = ('\n'.join(_valid_bal_lines()) + '\n').encode()
    plain = tmp_path / 'plain.txt'
    plain.write_bytes(text)
    packed = tmp_path / 'problem.txt'
    packed.write_bytes(compress(text))
    a, b = read_bal(plain), read_bal(packed)
    np.testing.assert_array_equal(a.obs.pixels, b.obs.pixels)
    np.testing.assert_array_equal(a.centers_w, b.centers_w)
    assert detect_problem_format(packed) == 'bal'


@pytest.mark.parametrize('compress', [bz2.compress, gzip.compress, lzma.compress])
def test_damaged_compressed_bal_file_raises(
        tmp_path: Path, compress: Callable[[bytes], bytes]) -> None:
    """A compressed file cut short, or with its stream damaged, is a FormatError naming it."""
    data = compress(('\n'.join(_valid_bal_lines() * 20) + '\n').encode())
    cut = tmp_path / 'cut.txt'
    cut.write_bytes(data[:len(data) // 2])
    with pytest.raises(FormatError, match=f'{re.escape(str(cut))}: damaged'):
        read_bal(cut)
    flipped = bytearray(data)
    flipped[len(data) // 2:len(data) // 2 + 8] = b'\x00' * 8
    bad = tmp_path / 'bad.txt'
    bad.write_bytes(bytes(flipped))
    with pytest.raises(FormatError, match=f'{re.escape(str(bad))}: damaged'):
        read_bal(bad)


def test_empty_and_binary_bal_files_raise(tmp_path: Path) -> None:
    """An empty file and a non-text file are format errors."""
    empty = tmp_path / 'empty.txt'
    empty.write_text('\n\n')
    with pytest.raises(FormatError, match='empty file'):
        read_bal(empty)
    binary = tmp_path / 'binary.txt'
    binary.write_bytes(b'\xff\xfe\x00\x01')
    with pytest.raises(FormatError, match='not a text file'):
        read_bal(binary)
