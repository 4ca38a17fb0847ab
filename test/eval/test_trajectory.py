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
"""Tests of pmba_ros.eval.trajectory: the Trajectory record and the TUM/EuRoC/KITTI formats."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pmba_ros.core import so3
from pmba_ros.errors import EvaluationError, FormatError
from pmba_ros.eval.trajectory import (
    detect_format,
    read_euroc_csv,
    read_kitti,
    read_times,
    read_trajectory,
    read_tum,
    Trajectory,
    write_tum,
)
import pytest

from ..conftest import SHARED_DATA as DATA

EVO_DIR = DATA / 'trajectories' / 'evo'
needs_data = pytest.mark.skipif(not EVO_DIR.is_dir(), reason=f'{EVO_DIR} is not available')


@pytest.fixture
def rng() -> np.random.Generator:
    """Seeded random generator."""
    return np.random.default_rng(20240611)


def random_trajectory(rng: np.random.Generator, n: int) -> Trajectory:
    """Return a trajectory with increasing stamps and random poses."""
    stamps = 1.3e9 + np.cumsum(rng.uniform(0.01, 0.1, n))
    return Trajectory(stamps, rng.normal(scale=5.0, size=(n, 3)),
                      so3.exp(rng.normal(size=(n, 3))))


def write_text(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` and return the path."""
    path.write_text(text, encoding='utf-8')
    return path


# --------------------------------------------------------------------------------------------
# Trajectory
# --------------------------------------------------------------------------------------------

def test_trajectory_arrays_are_read_only_copies(rng: np.random.Generator) -> None:
    """The record copies its inputs and cannot be modified through its arrays."""
    positions = rng.normal(size=(4, 3))
    traj = Trajectory(np.arange(4.0), positions, np.broadcast_to(np.eye(3), (4, 3, 3)))
    positions[0, 0] = 1e6
    assert traj.positions_xyz[0, 0] != 1e6
    for arr in (traj.stamps_s, traj.positions_xyz, traj.R_wc):
        assert not arr.flags.writeable
        with pytest.raises(ValueError, match='read-only'):
            arr[0] = 0.0
    assert len(traj) == 4


def test_trajectory_take_returns_new_subset(rng: np.random.Generator) -> None:
    """take() selects poses by index without touching the original."""
    traj = random_trajectory(rng, 6)
    sub = traj.take([4, 1])
    np.testing.assert_array_equal(sub.stamps_s, traj.stamps_s[[4, 1]])
    np.testing.assert_array_equal(sub.R_wc, traj.R_wc[[4, 1]])
    assert len(traj) == 6


@pytest.mark.parametrize(('stamps', 'positions', 'rotations'), [
    (np.zeros(3), np.zeros((2, 3)), np.zeros((3, 3, 3))),
    (np.zeros(2), np.zeros((2, 3)), np.zeros((2, 3))),
    (np.zeros((2, 1)), np.zeros((2, 3)), np.zeros((2, 3, 3))),
])
def test_trajectory_raises_on_inconsistent_shapes(stamps: np.ndarray, positions: np.ndarray,
                                                  rotations: np.ndarray) -> None:
    """Shapes must be (N,), (N, 3) and (N, 3, 3)."""
    with pytest.raises(EvaluationError, match='Trajectory needs stamps_s'):
        Trajectory(stamps, positions, rotations)


def test_trajectory_raises_on_non_finite_values() -> None:
    """Non-finite (NaN) positions are rejected."""
    with pytest.raises(EvaluationError, match='positions_xyz contains non-finite'):
        Trajectory(np.zeros(1), np.full((1, 3), np.nan), np.eye(3)[None])


# --------------------------------------------------------------------------------------------
# Round trips and determinism
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize('n', [1, 2, 57])
def test_tum_round_trip(tmp_path: Path, rng: np.random.Generator, n: int) -> None:
    """write_tum -> read_tum returns the stamps exactly and the poses to 9 digits."""
    traj = random_trajectory(rng, n)
    path = tmp_path / 'traj.txt'
    write_tum(path, traj)
    back = read_tum(path)
    np.testing.assert_array_equal(back.stamps_s, traj.stamps_s)
    np.testing.assert_allclose(back.positions_xyz, traj.positions_xyz, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(back.R_wc, traj.R_wc, atol=1e-8)
    assert detect_format(path) == 'tum'


def test_write_tum_is_byte_identical_run_to_run(tmp_path: Path,
                                                rng: np.random.Generator) -> None:
    """Writing the same trajectory twice gives the same bytes, and re-writing is stable."""
    traj = random_trajectory(rng, 20)
    first, second, third = tmp_path / 'a.txt', tmp_path / 'b.txt', tmp_path / 'c.txt'
    write_tum(first, traj)
    write_tum(second, traj)
    assert first.read_bytes() == second.read_bytes()
    write_tum(third, read_tum(first))
    lines_1 = first.read_text().splitlines()
    lines_3 = third.read_text().splitlines()
    # stamps and positions survive a second round trip unchanged
    assert [ln.split()[:4] for ln in lines_1] == [ln.split()[:4] for ln in lines_3]


def test_write_tum_quaternion_has_non_negative_w(tmp_path: Path,
                                                 rng: np.random.Generator) -> None:
    """The quaternion sign is canonical (w >= 0), so q and -q write the same line."""
    traj = random_trajectory(rng, 30)
    write_tum(tmp_path / 't.txt', traj)
    mat = np.loadtxt(tmp_path / 't.txt')
    assert np.all(mat[:, 7] >= 0.0)


def test_write_tum_raises_format_error_on_unwritable_path(tmp_path: Path,
                                                          rng: np.random.Generator) -> None:
    """A missing directory is reported as a FormatError naming the path."""
    with pytest.raises(FormatError, match='cannot write trajectory file'):
        write_tum(tmp_path / 'missing' / 't.txt', random_trajectory(rng, 2))


# --------------------------------------------------------------------------------------------
# Readers
# --------------------------------------------------------------------------------------------

def test_read_tum_skips_comments_and_blank_lines(tmp_path: Path) -> None:
    """Comment and empty lines are ignored; quaternions are x, y, z, w and normalized."""
    path = write_text(tmp_path / 't.txt',
                      '# header\n\n1.5 1 2 3 0 0 0 2\n  \n2.5 4 5 6 0 0 1 1\n# tail\n')
    traj = read_tum(path)
    np.testing.assert_array_equal(traj.stamps_s, [1.5, 2.5])
    np.testing.assert_array_equal(traj.positions_xyz, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_allclose(traj.R_wc[0], np.eye(3), atol=1e-15)
    np.testing.assert_allclose(traj.R_wc[1], so3.exp(np.array([0.0, 0.0, np.pi / 2])),
                               atol=1e-15)


def test_read_tum_normalizes_quaternions_whose_norm_overflows(tmp_path: Path) -> None:
    """A quaternion of 1e200 is the rotation of its direction (was a wrong one, silently)."""
    path = write_text(tmp_path / 't.txt', '1 0 0 0 0 0 1e200 1e200\n2 0 0 0 1e300 0 0 0\n')
    traj = read_tum(path)
    np.testing.assert_allclose(traj.R_wc[0], so3.exp(np.array([0.0, 0.0, np.pi / 2])),
                               atol=1e-15)
    np.testing.assert_allclose(traj.R_wc[1], so3.exp(np.array([np.pi, 0.0, 0.0])), atol=1e-15)


def test_read_euroc_csv_reads_wxyz_and_nanoseconds(tmp_path: Path) -> None:
    """Rows of EuRoC CSV are t_ns, p, q_wxyz, then ignored columns; 8 columns suffice."""
    rows = ('#timestamp, p_x, p_y, p_z, q_w, q_x, q_y, q_z\n'
            '1403715524907143168,1,2,3,0.7071067811865476,0,0,0.7071067811865476,9,9\n'
            '1403715524912143104, 4, 5, 6, 1, 0, 0, 0\n')
    traj = read_euroc_csv(write_text(tmp_path / 'gt.csv', rows))
    np.testing.assert_array_equal(traj.stamps_s,
                                  np.array([1403715524907143168, 1403715524912143104.0]) / 1e9)
    np.testing.assert_allclose(traj.R_wc[0], so3.exp(np.array([0.0, 0.0, np.pi / 2])),
                               atol=1e-15)
    np.testing.assert_array_equal(traj.positions_xyz[1], [4, 5, 6])
    assert detect_format(tmp_path / 'gt.csv') == 'euroc'


def test_a_tum_file_with_commas_is_read_as_tum(tmp_path: Path) -> None:
    """Comma-separated with stamps in seconds: TUM with commas, not EuRoC's nanoseconds.

    It was read as EuRoC CSV (stamps / 1e9, quaternion w first): "no matching timestamps".
    """
    spaced = write_text(tmp_path / 'gt.tum', '1.5 1 2 3 0 0 0.7071067811865476 '
                        '0.7071067811865476\n1.6 4 5 6 0 0 0 1\n')
    commas = write_text(tmp_path / 'commas.tum', spaced.read_text().replace(' ', ','))
    assert detect_format(commas) == 'tum'
    a, b = read_trajectory(spaced), read_trajectory(commas)
    np.testing.assert_array_equal(a.stamps_s, b.stamps_s)
    np.testing.assert_array_equal(a.R_wc, b.R_wc)


C45 = '0.7071067811865476'
"""Both non-zero components of a quaternion of 90 degrees about z."""

EUROC_HEADER = ('#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],'
                'q_RS_y [],q_RS_z []')
"""The header of EuRoC's ground-truth files (its first 8 columns)."""


@pytest.mark.parametrize(('name', 'lines'), [
    # EuRoC's own header: w first, [ns].
    ('gt.csv', [EUROC_HEADER, f'1500000000,1,2,3,{C45},0,0,{C45}',
                '1600000000,4,5,6,1,0,0,0']),
    # Short names, stamps written as seconds: was read as TUM, x first (RPE 6x too large).
    ('gt.csv', ['#timestamp, p_x,p_y,p_z,q_w,q_x,q_y,q_z', f'1.5,1,2,3,{C45},0,0,{C45}',
                '1.6,4,5,6,1,0,0,0']),
    # A header without '#' (was "TUM column 1 is not a finite number: 'timestamp'").
    ('gt.csv', ['timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z', f'1500000000,1,2,3,{C45},0,0,{C45}',
                '1600000000,4,5,6,1,0,0,0']),
    ('gt.txt', ['timestamp tx ty tz qx qy qz qw', f'1.5 1 2 3 0 0 {C45} {C45}',
                '1.6 4 5 6 0 0 0 1']),
    # TUM's header after a comment of prose; and TUM's order with stamps in ns.
    ('gt.txt', ['# ground truth', '# timestamp tx ty tz qx qy qz qw',
                f'1.5 1 2 3 0 0 {C45} {C45}', '1.6 4 5 6 0 0 0 1']),
    ('gt.txt', ['# timestamp [ns] tx ty tz qx qy qz qw', f'1500000000 1 2 3 0 0 {C45} {C45}',
                '1600000000 4 5 6 0 0 0 1']),
])
def test_a_header_decides_quaternion_order_and_stamp_unit(tmp_path: Path, name: str,
                                                          lines: list[str]) -> None:
    """A header naming the columns is read as such, whatever the stamps look like."""
    traj = read_trajectory(write_text(tmp_path / name, '\n'.join(lines) + '\n'))
    np.testing.assert_allclose(traj.stamps_s, [1.5, 1.6], rtol=1e-15)
    np.testing.assert_array_equal(traj.positions_xyz, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_allclose(traj.R_wc, [so3.exp(np.array([0.0, 0.0, np.pi / 2])),
                                           np.eye(3)], atol=1e-15)


@pytest.mark.parametrize(('text', 'fmt', 'match'), [
    ('#timestamp, p_x,p_y,p_z,q_w,q_x,q_y,q_z\n1.5,1,2,3,1,0,0,0\n', 'tum',
     r'gt\.txt:1: the header names the quaternion w, x, y, z, but the file is read as TUM'),
    ('# timestamp tx ty tz qx qy qz qw\n1,1,2,3,0,0,0,1\n', 'euroc',
     r'gt\.txt:1: the header names the quaternion x, y, z, w, but .* as EuRoC CSV'),
    ('# timestamp [ns] tx ty tz qx qy qz qw\n1 1 2 3 0 0 0 1\n', 'tum',
     r'gt\.txt:1: .*x, y, z, w, stamps in ns, but the file is read as TUM'),
    ('# timestamp [us] tx ty tz qx qy qz qw\n1 1 2 3 0 0 0 1\n', 'auto',
     r'gt\.txt:1: the header gives the stamps in \[us\]; the readers take ns or s'),
    ('# t x y z qx qw qy qz\n1 1 2 3 0 1 0 0\n', 'auto',
     r'gt\.txt:1: the header names the columns t, x, y, z, qx, qw, qy, qz; the readers'),
])
def test_a_header_that_contradicts_the_format_is_an_error(tmp_path: Path, text: str, fmt: str,
                                                          match: str) -> None:
    """A header against the format asked for, or in no reader's order: a FormatError."""
    with pytest.raises(FormatError, match=match):
        read_trajectory(write_text(tmp_path / 'gt.txt', text), fmt)


def test_a_header_not_understood_is_a_warning(tmp_path: Path,
                                              caplog: pytest.LogCaptureFixture) -> None:
    """Names of no known column: a warning naming the file, and the format's order."""
    path = write_text(tmp_path / 'gt.txt', '# a b c d e f g h\n1 1 2 3 0 0 0 1\n')
    with caplog.at_level('WARNING', logger='pmba_ros.eval.layout'):
        traj = read_trajectory(path)
    np.testing.assert_array_equal(traj.R_wc, [np.eye(3)])
    assert len(caplog.records) == 1
    assert caplog.records[0].getMessage().startswith(
        f"{path}:1: the header '# a b c d e f g h' names no columns the readers know")


def test_stamps_tell_the_format_of_a_file_without_header(tmp_path: Path) -> None:
    """Whole-number stamps in exponent form are EuRoC's ns; a '.tum' name is TUM (were not)."""
    sci = write_text(tmp_path / 'gt.csv', '1.0e+09,1,2,3,1,0,0,0\n1.1e+09,4,5,6,1,0,0,0\n')
    assert detect_format(sci) == 'euroc'
    np.testing.assert_array_equal(read_trajectory(sci).stamps_s, [1.0, 1.1])
    ints = write_text(tmp_path / 'gt.tum', '0,1,2,3,0,0,0,1\n1,4,5,6,0,0,0,1\n')
    assert detect_format(ints) == 'tum'
    np.testing.assert_array_equal(read_trajectory(ints).stamps_s, [0.0, 1.0])


def test_stamps_note_says_how_stamps_were_read(tmp_path: Path) -> None:
    """A note says how stamps were read: as EuRoC nanoseconds, they look like seconds."""
    path = write_text(tmp_path / 'gt.csv', '1.5,1,2,3,1,0,0,0\n1.6,4,5,6,1,0,0,0\n')
    assert read_trajectory(path).stamps_note == 'read as seconds (TUM)'
    euroc = read_trajectory(path, 'euroc')
    assert euroc.stamps_note == 'read as nanoseconds (EuRoC CSV); these look like seconds'
    assert euroc.take([1]).stamps_note == euroc.stamps_note


def test_read_kitti_uses_index_or_given_stamps(tmp_path: Path,
                                               rng: np.random.Generator) -> None:
    """KITTI poses get index stamps unless stamps are given; rotations project on request."""
    rotations = so3.exp(rng.normal(size=(3, 3)))
    positions = rng.normal(size=(3, 3))
    mat = np.concatenate([rotations, positions[:, :, None]], axis=2).reshape(3, 12)
    path = tmp_path / 'poses.txt'
    np.savetxt(path, mat, fmt='%.6e')
    traj = read_kitti(path)
    np.testing.assert_array_equal(traj.stamps_s, [0.0, 1.0, 2.0])
    np.testing.assert_allclose(traj.positions_xyz, positions, rtol=1e-6)
    np.testing.assert_allclose(traj.R_wc, rotations, atol=1e-6)
    projected = read_kitti(path, project_to_so3=True)
    np.testing.assert_allclose(projected.R_wc, rotations, atol=1e-6)
    gram = np.einsum('nji,njk->nik', projected.R_wc, projected.R_wc)
    np.testing.assert_allclose(gram, np.broadcast_to(np.eye(3), gram.shape), atol=1e-14)
    np.testing.assert_array_equal(read_kitti(path, stamps=[0.5, 0.6, 0.7]).stamps_s,
                                  [0.5, 0.6, 0.7])
    assert detect_format(path) == 'kitti'
    assert len(read_trajectory(path)) == 3


@pytest.mark.parametrize(('text', 'reader', 'match'), [
    ('1 2 3 4 5 6 7 8\n1 2 3\n', read_tum, r'bad\.txt:2: TUM lines need 8 values'),
    ('# c\n1 2 3 4 5 6 7 8 9\n', read_tum, r'bad\.txt:2: TUM lines need 8 values.*got 9'),
    ('1 2 3 4 abc 6 7 8\n', read_tum, r"bad\.txt:1: TUM column 5 is not a finite number: 'abc'"),
    ('1 2 3 nan 0 0 0 1\n', read_tum, r'bad\.txt:1: TUM column 4 is not a finite number'),
    # Numbers only Python's float() reads ('1_0', other scripts' digits) were read.
    ('1 2 3 4 0 0 0 1\n2 2 3 1_0 0 0 0 1\n', read_tum,
     r"bad\.txt:2: TUM column 4 is not a finite number: '1_0'"),
    ('1,2,3,4,1,0,0,0\n2,2,3,4,\u0661,0,0,0\n', read_euroc_csv,
     r"bad\.txt:2: EuRoC CSV column 5 is not a finite number: '\u0661'"),
    ('1 2 3 4 0 0 0 0\n', read_tum, r'bad\.txt:1: TUM quaternion is zero'),
    # Was "zero norm": its squares underflow, but it is not zero.
    ('1 2 3 4 0 0 1e-200 1e-200\n', read_tum,
     r'bad\.txt:1: TUM quaternion has norm 1\.41e-200, too small to normalize'),
    ('# only a comment\n', read_tum, r'bad\.txt: no TUM poses found'),
    ('1,2,3,4,5,6,7\n', read_euroc_csv, r'bad\.txt:1: EuRoC CSV lines need at least 8'),
    ('1 0 0 0 0 1 0 0 0 0 1\n', read_kitti, r'bad\.txt:1: KITTI lines need 12 values'),
    ('2 0 0 0 0 1 0 0 0 0 1 0\n', read_kitti, r'bad\.txt:1: KITTI rotation block is not'),
])
def test_readers_raise_format_error_naming_file_and_line(tmp_path: Path, text: str,
                                                         reader: object, match: str) -> None:
    """Malformed files raise FormatError with file, line and problem."""
    path = write_text(tmp_path / 'bad.txt', text)
    with pytest.raises(FormatError, match=match):
        reader(path)  # type: ignore[operator]


@pytest.mark.parametrize(('text', 'reader', 'match'), [
    ('1 0 0 0 0 0 0 1\n2 0 1e300 0 0 0 0 1\n', read_tum,
     r'bad\.txt:2: TUM position coordinate 1e\+300 is beyond 1e\+150 m'),
    ('1,0,0,0,1,0,0,0\n2,0,0,-1e200,1,0,0,0\n', read_euroc_csv,
     r'bad\.txt:2: EuRoC CSV position coordinate -1e\+200 is beyond'),
    ('1 0 0 1e151 0 1 0 0 0 0 1 0\n', read_kitti,
     r'bad\.txt:1: KITTI position coordinate 1e\+151'),
])
def test_absurd_positions_are_refused_naming_file_and_line(tmp_path: Path, text: str,
                                                           reader: object, match: str) -> None:
    """A coordinate of 1e300 m: a FormatError (ATE / RPE were printed as inf / nan, exit 0)."""
    path = write_text(tmp_path / 'bad.txt', text)
    with pytest.raises(FormatError, match=match):
        reader(path)  # type: ignore[operator]


def test_positions_up_to_the_bound_are_read(tmp_path: Path) -> None:
    """A coordinate of 1e150 m is read (nothing a real trajectory holds is refused)."""
    path = write_text(tmp_path / 't.txt', '1 1e150 -1e150 0 0 0 0 1\n')
    np.testing.assert_array_equal(read_tum(path).positions_xyz, [[1e150, -1e150, 0]])


def test_read_kitti_raises_on_stamp_count_mismatch(tmp_path: Path) -> None:
    """Given stamps must have one entry per pose."""
    path = write_text(tmp_path / 'k.txt', '1 0 0 0 0 1 0 0 0 0 1 0\n')
    with pytest.raises(FormatError, match='1 KITTI poses but 2 stamps'):
        read_kitti(path, stamps=[0.0, 1.0])


def test_read_times_refuses_a_time_beyond_a_ros_stamp(tmp_path: Path) -> None:
    """A KITTI time of 1e300 s: a FormatError naming file and line.

    ``pmba import-tracks`` stamped its bag with it: numpy overflow warnings, then a failure
    deep in serialization ("'i' format requires ..."), naming neither.
    """
    path = write_text(tmp_path / 'times.txt', '0.0\n# comment\n0.1\n1e300\n0.3\n')
    with pytest.raises(FormatError, match=r'times\.txt:4: time 1e\+300 s is beyond'):
        read_times(path)
    path = write_text(tmp_path / 'times.txt', '0.0\n-3e9\n')
    with pytest.raises(FormatError, match=r'times\.txt:2: time -3e\+09 s is beyond'):
        read_times(path)
    np.testing.assert_array_equal(read_times(write_text(tmp_path / 'ok.txt', '0\n470.5\n')),
                                  [0.0, 470.5])


def test_read_times_refuses_times_that_decrease(tmp_path: Path) -> None:
    """Times out of order: a FormatError naming the line (they paired poses wrongly, silently).

    Line i is the time of pose i, so a decreasing file gave an ATE 2x the true one and an RPE
    of 2 m, without a word.
    """
    path = write_text(tmp_path / 'times.txt', '0.0\n0.1\n# comment\n0.1\n0.05\n0.3\n')
    with pytest.raises(FormatError,
                       match=r'times\.txt:5: time 0\.05 s is before the 0\.1 s of line 4'):
        read_times(path)


def test_read_trajectory_raises_on_missing_file(tmp_path: Path) -> None:
    """A missing file is a FormatError (a PmbaError), not a bare OSError."""
    with pytest.raises(FormatError, match=r'nope\.txt: cannot read trajectory file'):
        read_trajectory(tmp_path / 'nope.txt')


def test_read_trajectory_raises_on_unknown_format(tmp_path: Path) -> None:
    """Unknown format names and undetectable files are rejected."""
    path = write_text(tmp_path / 'x.txt', '1 2 3\n')
    with pytest.raises(FormatError, match="unknown trajectory format 'g2o'"):
        read_trajectory(path, 'g2o')
    with pytest.raises(FormatError, match=r'x\.txt:1: cannot detect the trajectory format: 3'):
        read_trajectory(path)


@pytest.mark.parametrize(('fmt', 'reader'), [('tum', read_tum), ('kitti', read_kitti)])
def test_read_trajectory_explicit_format_matches_reader(tmp_path: Path, fmt: str,
                                                        reader: object) -> None:
    """read_trajectory(path, fmt) equals the format's own reader."""
    text = {'tum': '1 1 2 3 0 0 0 1\n2 1 2 4 0 0 0 1\n',
            'kitti': '1 0 0 1 0 1 0 2 0 0 1 3\n1 0 0 1 0 1 0 2 0 0 1 4\n'}[fmt]
    path = write_text(tmp_path / 't.txt', text)
    ours = read_trajectory(path, fmt)
    theirs = reader(path)  # type: ignore[operator]
    np.testing.assert_array_equal(ours.positions_xyz, theirs.positions_xyz)
    np.testing.assert_array_equal(ours.stamps_s, theirs.stamps_s)


# --------------------------------------------------------------------------------------------
# Real files, evo's readers as the oracle
# --------------------------------------------------------------------------------------------

@needs_data
@pytest.mark.parametrize(('name', 'fmt'), [
    ('freiburg1_xyz-rgbdslam.txt', 'tum'),
    ('fr2_desk_ORB.txt', 'tum'),
    ('V102.txt', 'tum'),
    ('V102_groundtruth.csv', 'euroc'),
    ('KITTI_00_gt.txt', 'kitti'),
])
def test_readers_match_evo_file_interface(name: str, fmt: str) -> None:
    """Stamps, positions and rotations equal evo's readers on the shared data."""
    file_interface = pytest.importorskip('evo.tools.file_interface')
    path = EVO_DIR / name
    ours = read_trajectory(path)
    assert detect_format(path) == fmt
    if fmt == 'kitti':
        theirs = file_interface.read_kitti_poses_file(str(path))
    else:
        reader = (file_interface.read_euroc_csv_trajectory if fmt == 'euroc'
                  else file_interface.read_tum_trajectory_file)
        theirs = reader(str(path))
        np.testing.assert_array_equal(ours.stamps_s, theirs.timestamps)
    np.testing.assert_array_equal(ours.positions_xyz, theirs.positions_xyz)
    rotations = np.array([pose[:3, :3] for pose in theirs.poses_se3])
    np.testing.assert_allclose(ours.R_wc, rotations, atol=1e-12)
