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
"""Photo-collection files damaged at random: read, or refused with a FormatError, never a crash.

Each case damages one file of a small model as a disk or a copy does (cut short, bits
flipped, a span zeroed or repeated, a token such as ``nan`` or ``1e308`` written into it)
and reads it as ``pmba solve`` does, up to the problem it solves.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
import random
import shutil
from test.io.test_bundler import _bundle_text

import numpy as np
from pmba_ros.core.problem import BAProblem
from pmba_ros.errors import FormatError
from pmba_ros.io import bal, bundler, colmap
from pmba_ros.sim.damage import damage_bytes
from pmba_ros.sim.scenes import street_scene
import pytest

CASES = 40
"""Damaged copies per format."""


@pytest.fixture(scope='module')
def small() -> BAProblem:
    """Return a small street (6 cameras, 120 points)."""
    return street_scene(1, n_cams=6, n_points=120, max_track_length=4).start


def _damaged_copies(source: Path, tmp: Path, read: Callable[[Path], object], what: str) -> int:
    """Read CASES damaged copies of the files in ``source``; return how many were refused.

    A refusal names the file, or the format (``what``) when the whole model is inconsistent.
    """
    refused = 0
    files = sorted(p.name for p in source.iterdir() if p.is_file())
    for seed in range(CASES):
        rng = random.Random(seed)
        copy = tmp / f'case{seed}'
        shutil.copytree(source, copy)
        name = rng.choice(files)
        (copy / name).write_bytes(damage_bytes((copy / name).read_bytes(), rng))
        try:
            read(copy)
        except FormatError as err:   # anything else fails the test with its traceback
            assert str(copy) in str(err) or what in str(err), f'case {seed}: {err}'
            refused += 1
    return refused


@pytest.mark.parametrize('binary', [False, True], ids=['text', 'binary'])
def test_damaged_colmap_models_are_read_or_refused(tmp_path: Path, small: BAProblem,
                                                   binary: bool) -> None:
    """Every damaged copy of a COLMAP model reads to a problem or names what is wrong."""
    source = tmp_path / 'model'
    colmap.write_colmap(source, colmap.from_problem(small), binary=binary)
    refused = _damaged_copies(source, tmp_path,
                              lambda d: colmap.to_problem(colmap.read_colmap(d)), 'COLMAP')
    assert 0 < refused < CASES   # the damage is real, and some of it is readable


def test_damaged_bal_and_bundler_files_are_read_or_refused(tmp_path: Path,
                                                           small: BAProblem) -> None:
    """The same for a BAL problem and a Bundler file."""
    (tmp_path / 'bal').mkdir()
    bal.write_bal(tmp_path / 'bal' / 'problem.txt', small)
    (tmp_path / 'bundler').mkdir()
    (tmp_path / 'bundler' / 'bundle.out').write_text(_bundle_text(small))
    refused = _damaged_copies(tmp_path / 'bal', tmp_path / 'b',
                              lambda d: bal.read_bal(d / 'problem.txt'), 'BAL')
    assert 0 < refused < CASES
    refused = _damaged_copies(tmp_path / 'bundler', tmp_path / 'u',
                              lambda d: bundler.to_problem(bundler.read_bundler(d / 'bundle.out')),
                              'Bundler')
    assert 0 < refused < CASES


def test_damage_changes_the_bytes() -> None:
    """Damage changes a file (so the cases above test something)."""
    data = bytes(range(256)) * 8
    changed = [damage_bytes(data, random.Random(seed)) != data for seed in range(200)]
    assert np.mean(changed) > 0.95
