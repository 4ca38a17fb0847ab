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
"""Tests of pmba_ros.io.parallaxba_files: Euler convention, fake-pile, DLT, malformed files."""

from __future__ import annotations

from pathlib import Path
import re
import time

import numpy as np
from pmba_ros._typing import FloatArray
from pmba_ros.core import so3
from pmba_ros.core.camera import Intrinsics, project
from pmba_ros.core.problem import BAProblem, make_problem
from pmba_ros.errors import FormatError
from pmba_ros.io.parallaxba_files import (
    euler_to_R_cw,
    read_parallaxba,
    triangulate_points,
)
from pmba_ros.sim.scenes import street_scene, table3_scene
import pytest

from ..conftest import SHARED_DATA

FAKE_PILE = SHARED_DATA / 'parallaxba' / 'fake-pile'
needs_data = pytest.mark.skipif(not FAKE_PILE.is_dir(), reason='shared fake-pile not available')


def reprojection_errors_px(problem: BAProblem, points_w: FloatArray) -> FloatArray:
    """Return |project(R_wc^T (X - C)) - pixel| per observation (px)."""
    obs = problem.obs
    h_c = np.einsum('kji,kj->ki', problem.R_wc[obs.cam_idx],
                    points_w[obs.feat_idx] - problem.centers_w[obs.cam_idx])
    err: FloatArray = np.linalg.norm(
        project(h_c, problem.intrinsics, obs.cam_idx) - obs.pixels, axis=1)
    return err


def test_euler_to_R_cw_matches_pdf_eq4_element_matrices() -> None:
    """R = RX(gamma) RY(beta) RZ(alpha) with the PDF's signs; alpha is the Z angle."""
    a, b, g = 0.3, -0.2, 0.7
    ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
    RZ = np.array([[ca, sa, 0], [-sa, ca, 0], [0, 0, 1]])
    RY = np.array([[cb, 0, -sb], [0, 1, 0], [sb, 0, cb]])
    RX = np.array([[1, 0, 0], [0, cg, sg], [0, -sg, cg]])
    np.testing.assert_allclose(euler_to_R_cw(np.array([a, b, g])), RX @ RY @ RZ, atol=1e-15)
    np.testing.assert_allclose(euler_to_R_cw(np.array([a, 0.0, 0.0])), RZ, atol=1e-15)
    batch = euler_to_R_cw(np.random.default_rng(0).normal(size=(3, 2, 3)))
    assert batch.shape == (3, 2, 3, 3)
    np.testing.assert_allclose(batch @ np.swapaxes(batch, -1, -2), np.broadcast_to(np.eye(3),
                               batch.shape), atol=1e-14)
    with pytest.raises(ValueError, match='expected shape'):
        euler_to_R_cw(np.zeros(4))


@needs_data
def test_read_fake_pile_counts_and_intrinsics() -> None:
    """fake-pile: 47 cameras, 11318 features, 26050 observations, K from intrinsic_matrix."""
    t0 = time.perf_counter()
    problem = read_parallaxba(FAKE_PILE)
    assert time.perf_counter() - t0 < 1.0
    assert (problem.n_cams, problem.n_feats, problem.n_obs) == (47, 11318, 26050)
    assert problem.points_w is None
    assert problem.dropped == {}
    np.testing.assert_allclose(problem.intrinsics.fx, 1071.18)
    np.testing.assert_allclose(problem.intrinsics.fy, 1070.36)
    np.testing.assert_allclose(problem.intrinsics.cx, 646.269)
    np.testing.assert_allclose(problem.intrinsics.cy, 350.651)
    np.testing.assert_allclose(problem.R_wc[0], np.eye(3), atol=1e-15)
    np.testing.assert_allclose(problem.centers_w[1], [0.7382162898, 0.0008472639, 0.6745635562])
    # First feature line: "2 0 512.82000 285.54250 1 553.61260 293.64740".
    np.testing.assert_array_equal(problem.obs.cam_idx[:2], [0, 1])
    np.testing.assert_allclose(problem.obs.pixels[:2], [[512.82, 285.5425], [553.6126, 293.6474]])
    counts = np.diff(problem.feature_offsets())
    assert counts.min() == 2
    assert counts.max() == 11


@needs_data
def test_read_fake_pile_from_explicit_files_equals_directory() -> None:
    """Passing the Cam file and the other files explicitly gives the same problem."""
    auto = read_parallaxba(FAKE_PILE)
    explicit = read_parallaxba(FAKE_PILE / 'Cam.txt', FAKE_PILE / 'Feature.pmba',
                               FAKE_PILE / 'intrinsic_matrix.txt')
    np.testing.assert_array_equal(auto.R_wc, explicit.R_wc)
    np.testing.assert_array_equal(auto.obs.pixels, explicit.obs.pixels)


@needs_data
def test_dlt_on_fake_pile_gives_sources_median_reprojection() -> None:
    """DLT with the Cam.txt poses: 0.63 px median reprojection, every point in front."""
    problem = read_parallaxba(FAKE_PILE)
    points = triangulate_points(problem)
    assert points.shape == (problem.n_feats, 3)
    err = reprojection_errors_px(problem, points)
    assert np.median(err) == pytest.approx(0.63, abs=0.005)
    obs = problem.obs
    depth = np.einsum('ki,ki->k', problem.R_wc[obs.cam_idx][:, :, 2],
                      points[obs.feat_idx] - problem.centers_w[obs.cam_idx])
    assert np.all(depth > 0)


@pytest.mark.parametrize('scene_fn', [table3_scene, street_scene])
def test_triangulate_points_recovers_noise_free_points(scene_fn: object) -> None:
    """Without pixel noise DLT returns the true points, including far and collinear ones."""
    assert callable(scene_fn)
    scene = scene_fn(seed=2, noise_px=0.0)
    points = triangulate_points(scene.gt)
    assert scene.gt.points_w is not None
    rel = (np.linalg.norm(points - scene.gt.points_w, axis=1)
           / np.linalg.norm(scene.gt.points_w - scene.gt.centers_w[0], axis=1))
    assert np.max(rel) < 1e-6


def test_triangulate_points_at_infinity_is_finite_along_the_ray() -> None:
    """Cameras sharing one centre (pure rotation): points are clamped far along the ray."""
    R_wc = so3.exp(np.array([[0.0, 0.0, 0.0], [0.0, 0.05, 0.0], [0.02, 0.0, 0.0]]))
    centers = np.tile([1.0, 2.0, 3.0], (3, 1))
    intr = Intrinsics.uniform(3, 500.0, 500.0, 320.0, 240.0)
    directions = np.array([[0.1, 0.0, 1.0], [-0.1, 0.05, 1.0]])
    cam_idx = np.repeat(np.arange(3), 2)
    feat_idx = np.tile(np.arange(2), 3)
    h_c = np.einsum('kji,kj->ki', R_wc[cam_idx], directions[feat_idx])
    problem = make_problem(R_wc, centers, intr, cam_idx, feat_idx, project(h_c, intr, cam_idx))
    points = triangulate_points(problem, max_range_rel=1e6)
    assert np.all(np.isfinite(points))
    rays = points - centers[0]
    np.testing.assert_allclose(rays / np.linalg.norm(rays, axis=1, keepdims=True),
                               directions / np.linalg.norm(directions, axis=1, keepdims=True),
                               atol=1e-9)
    assert np.all(np.linalg.norm(rays, axis=1) > 1e5)
    with pytest.raises(ValueError, match='max_range_rel'):
        triangulate_points(problem, max_range_rel=0.0)


def _write_dataset(directory: Path, rng: np.random.Generator, *, eight_columns: bool = False,
                   with_xyz: bool = False) -> tuple[FloatArray, FloatArray, FloatArray,
                                                    FloatArray]:
    """Write a noise-free 4-camera dataset; return angles, centres, points, K."""
    n_cams, n_pts = 4, 6
    angles = rng.normal(0.0, 0.1, (n_cams, 3))
    centers = np.column_stack([np.arange(n_cams) * 0.5, rng.normal(0.0, 0.1, (n_cams, 2))])
    points = rng.uniform([-1.0, -1.0, 6.0], [2.0, 1.0, 9.0], (n_pts, 3))
    K = np.array([[800.0, 0.0, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]])
    R_cw = euler_to_R_cw(angles)
    cam_rows = np.column_stack([angles, centers])
    if eight_columns:
        cam_rows = np.column_stack([cam_rows, np.full(n_cams, 800.0), np.full(n_cams, 790.0)])
    np.savetxt(directory / 'Cam4.txt', cam_rows, fmt='%.17g')
    if not eight_columns:
        np.savetxt(directory / 'cal4.txt', K, fmt='%.17g')
    lines = []
    for j in range(n_pts):
        parts = [str(n_cams)]
        for i in range(n_cams):
            x = K @ (R_cw[i] @ (points[j] - centers[i]))  # [u v 1] ~ K R (F - C), eq. (2)
            uv = x[:2] / x[2] - (K[:2, 2] if eight_columns else 0.0)
            parts += [str(i), repr(float(uv[0])), repr(float(uv[1]))]
        lines.append(' '.join(parts))
    (directory / 'Feature4.txt').write_text('\n'.join(lines) + '\n')
    if with_xyz:
        np.savetxt(directory / 'XYZ4.txt', points, fmt='%.17g')
    return angles, centers, points, K


@pytest.mark.parametrize('eight_columns', [False, True])
def test_read_written_dataset_reprojects_exactly(tmp_path: Path, eight_columns: bool) -> None:
    """A dataset made with [u v 1] ~ K R (F - C) reads back with zero reprojection error."""
    angles, centers, points, _ = _write_dataset(tmp_path, np.random.default_rng(5),
                                                eight_columns=eight_columns)
    problem = read_parallaxba(tmp_path)
    assert (problem.n_cams, problem.n_feats, problem.n_obs) == (4, 6, 24)
    np.testing.assert_allclose(problem.R_wc, np.swapaxes(euler_to_R_cw(angles), 1, 2))
    np.testing.assert_allclose(problem.centers_w, centers)
    assert np.max(reprojection_errors_px(problem, points)) < 1e-8
    assert np.max(np.abs(triangulate_points(problem) - points)) < 1e-8
    if eight_columns:
        np.testing.assert_array_equal(problem.intrinsics.cx, 0.0)
        np.testing.assert_array_equal(problem.intrinsics.fy, 790.0)


def test_read_compressed_dataset(tmp_path: Path) -> None:
    """Files compressed with bzip2 (``.bz2``; ``data.pmba.bz2`` too) read as plain ones."""
    import bz2

    _write_dataset(tmp_path, np.random.default_rng(5), with_xyz=True)
    plain = read_parallaxba(tmp_path)
    packed = tmp_path / 'packed'
    packed.mkdir()
    for path in tmp_path.glob('*.txt'):
        name = 'data.pmba' if path.name.startswith('Feature') else path.name
        (packed / f'{name}.bz2').write_bytes(bz2.compress(path.read_bytes()))
    problem = read_parallaxba(packed)
    np.testing.assert_array_equal(problem.obs.pixels, plain.obs.pixels)
    np.testing.assert_array_equal(problem.centers_w, plain.centers_w)
    assert problem.points_w is not None and plain.points_w is not None
    np.testing.assert_array_equal(problem.points_w, plain.points_w)


def test_read_dataset_with_xyz_file(tmp_path: Path) -> None:
    """An XYZ file beside the others becomes points_w."""
    _, _, points, _ = _write_dataset(tmp_path, np.random.default_rng(6), with_xyz=True)
    problem = read_parallaxba(tmp_path)
    assert problem.points_w is not None
    np.testing.assert_allclose(problem.points_w, points)
    (tmp_path / 'XYZ4.txt').write_text('1 2 3\n')
    with pytest.raises(FormatError, match='1 points for 6 features'):
        read_parallaxba(tmp_path)


def test_missing_or_ambiguous_files_raise(tmp_path: Path) -> None:
    """Auto-detection needs exactly one file of each kind."""
    _write_dataset(tmp_path, np.random.default_rng(7))
    (tmp_path / 'Feature4.txt').rename(tmp_path / 'tracks.txt')
    with pytest.raises(FormatError, match='no feature file'):
        read_parallaxba(tmp_path)
    (tmp_path / 'tracks.txt').rename(tmp_path / 'Feature4.txt')
    (tmp_path / 'other.pmba').write_text('')
    with pytest.raises(FormatError, match=r'several feature files \(Feature4.txt, other.pmba\)'):
        read_parallaxba(tmp_path)
    (tmp_path / 'other.pmba').unlink()
    (tmp_path / 'cal4.txt').unlink()
    with pytest.raises(FormatError, match=r'no calibration \(K\) file'):
        read_parallaxba(tmp_path)


@pytest.mark.parametrize(('file_name', 'line', 'text', 'match'), [
    ('Feature4.txt', 2, '4 0 1.0 2.0 1 1.0 2.0', 'announces 4 observations but has 7 values'),
    ('Feature4.txt', 3, '2 0 1.0 2.0 7 1.0 2.0', 'camera index 7 is not an integer in'),
    ('Feature4.txt', 3, '2 0 1.0 2.0 1.5 1.0 2.0', 'camera index 1.5 is not an integer'),
    ('Feature4.txt', 1, '2 0 1.0 2.0 1 x 2.0', "non-numeric token 'x'"),
    ('Feature4.txt', 4, '2 0 1.0 nan 1 1.0 2.0', 'non-finite pixel'),
    ('Cam4.txt', 2, '0.1 0.2 0.3 1.0 2.0', 'row has 5 values, expected 6 or 8'),
    ('Cam4.txt', 3, '0.1 0.2 0.3 1.0 2.0 abc', "non-numeric token 'abc'"),
    # Numbers only Python's float() reads: read, or 'rows have 6 values, expected 6 or 8'.
    ('Cam4.txt', 3, '0.1 0.2 0.3 1.0 2.0 3_0', "non-numeric token '3_0'"),
    ('Feature4.txt', 2, '2 0 1.0 2.0 1 1_0 2.0', "non-numeric token '1_0'"),
    ('cal4.txt', 2, '0 7_90 240', "non-numeric token '7_90'"),
    ('Cam4.txt', 4, '0.1 0.2 0.3 1.0 2.0 inf', 'non-finite value'),
    # Its squares overflowed in the triangulation: a LinAlgError traceback before.
    ('Cam4.txt', 2, '0.1 0.2 0.3 1e300 2.0 3.0', 'camera centre coordinate 1e\\+300 beyond'),
    ('cal4.txt', 3, '0 0', 'expected 9 values'),
    ('cal4.txt', 2, '0 790 240 7', 'expected 9 values'),
    ('cal4.txt', 1, '800 5 320', 'skew'),
])
def test_malformed_parallaxba_files_raise_with_line(
        tmp_path: Path, file_name: str, line: int, text: str, match: str) -> None:
    """Malformed files raise FormatError naming the file, the line and the problem."""
    _write_dataset(tmp_path, np.random.default_rng(8))
    _refused_with_line(tmp_path, file_name, line, text, match)


def _refused_with_line(directory: Path, file_name: str, line: int, text: str,
                       match: str) -> None:
    """Replace ``line`` of ``file_name`` by ``text``: the read names the file, line, ``match``."""
    path = directory / file_name
    lines = path.read_text().splitlines()
    lines[line - 1] = text
    path.write_text('\n'.join(lines) + '\n')
    prefix = re.escape(str(path)) + (f':{line}: ' if 'skew' not in match else ': ')
    with pytest.raises(FormatError, match=f'{prefix}.*{match}'):
        read_parallaxba(directory)


@pytest.mark.parametrize(('file_name', 'line', 'text', 'match'), [
    ('Cam4.txt', 2, '0.1 0.2 0.3 0.5 0.0 0.0 1e200 790',
     r'camera 1 has focal length 1e\+200 beyond 1e\+150'),
    ('cal4.txt', 2, '0 1e200 240', r'K has focal length 1e\+200 beyond 1e\+150'),
    ('cal4.txt', 1, '800 0 -1e200', r'K has principal point coordinate -1e\+200 beyond'),
    ('XYZ4.txt', 3, '1e300 1 7', r'point 2 has coordinate 1e\+300 beyond 1e\+150'),
])
def test_absurd_focal_lengths_and_points_are_refused_with_line(
        tmp_path: Path, file_name: str, line: int, text: str, match: str) -> None:
    """Focal lengths and principal points beyond 1e150 and points beyond 1e150 are refused.

    Bounded as the BAL, COLMAP and Bundler readers bound them (io.text.check_bounded). Before,
    a focal length of 1e200 stopped the solve at non-finite residuals naming a camera index,
    not the file or line, and the XYZ solve of a point of 1e300 reported a converged answer.
    """
    _write_dataset(tmp_path, np.random.default_rng(8), eight_columns=file_name == 'Cam4.txt',
                   with_xyz=file_name == 'XYZ4.txt')
    _refused_with_line(tmp_path, file_name, line, text, match)
