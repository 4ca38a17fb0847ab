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
"""The harder-variant sweep (pmba_ros.sim.variants) through the global initialization.

Each variant must meet the issue's criterion (:meth:`InitAssessment.passed`): one BA that
converges (not an iteration cap) to within 1 % of the RMS of PMBA started from the problem's
own values on the same sub-problem, using at least 95 % of the reachable features.
"""

from __future__ import annotations

import json
import logging

from pmba_ros.core.problem import BAProblem
from pmba_ros.init.assess import assess
from pmba_ros.sim.scenes import street_scene
from pmba_ros.sim.variants import make_variants, VARIANTS
import pytest

from ..conftest import run_python, shared_file

logger = logging.getLogger(__name__)


def _sweep(problem: BAProblem, names: list[str], original: bool = True) -> None:
    failed = []
    for variant in make_variants(problem, names, seed=0)[0 if original else 1:]:
        assert variant.problem.points_w is not None
        row, res = assess(variant.problem, variant.problem.points_w,
                          outlier_ids=variant.outlier_ids)
        logger.info('%s: %s', variant.name, row)
        json.dumps(row.to_dict())  # the benchmark writes these rows as JSON
        # One BA; more only where dropped tracks were tried again.
        assert res.ba_invocations == 1 or res.report['summary']['inconsistent_tracks'] > 0
        if not row.passed():
            failed.append((variant.name, row))
    assert not failed, failed


@pytest.mark.parametrize('name', ['original', *sorted(VARIANTS)])
def test_simulated_street_variants_meet_the_criterion(name: str) -> None:
    """A 12-camera street (ground truth as the reference start) and each variant of it."""
    gt = street_scene(7, n_cams=12, n_points=400, noise_px=0.5, max_track_length=8).gt
    if name == 'original':
        _sweep(gt, [])
    else:
        _sweep(gt, [name], original=False)


@pytest.mark.slow
def test_ladybug_1800_variants_meet_the_criterion() -> None:
    """Sweep RootBA's Ladybug subsample and every variant of it."""
    from pmba_ros.io.bal import read_bal

    _sweep(read_bal(shared_file('bal', 'bal-ladybug-problem-49-7776-pre-shrink-1800.txt')),
           list(VARIANTS))


#: The focal3 street of test_mixed_focal_lengths_converge_alike, run in a fresh interpreter so
#: that its BLAS pools are numpy's default unless the test sizes them.
_MIXED_FOCAL = """
import sys
if sys.argv[1] == 'one':
    from pmba_ros._threads import limit_blas_threads
    limit_blas_threads()
from pmba_ros.core.compiled import chunks
chunks.max_threads = lambda: int(sys.argv[2])
from pmba_ros.core.models import ParallaxModel
from pmba_ros.init.assess import assess
from pmba_ros.sim.scenes import street_scene
from pmba_ros.sim.variants import make_variants
import numpy as np
gt = street_scene(0, n_cams=40, n_points=3000, max_track_length=12).gt
assert gt.n_obs >= 2 * chunks.CHUNK_OBSERVATIONS
v = make_variants(gt, ['focal3'], seed=0)[1]
row, res = assess(v.problem, v.problem.points_w, outlier_ids=v.outlier_ids)
p = res.problem
rays_c = ParallaxModel(p).evaluate(p.R_wc, p.centers_w, res.features).rays_c
behind = int(np.sum(np.sum(rays_c * p.obs.bearings_c, axis=1) < 0.0))
assert behind == 0, f'{behind} observations start behind their camera'
assert row.passed(rms_tolerance=0.001), row
assert row.ba_termination == 'function_tolerance', row
assert row.ba_iterations <= 32, row
"""


@pytest.mark.parametrize(('blas', 'threads'), [('one', 1), ('one', 2), ('default', 1),
                                               ('default', 2)])
def test_mixed_focal_lengths_converge_alike(blas: str, threads: int) -> None:
    """A 40-camera street with focal lengths from 1/3x to 3x, on any BLAS pool and chunking.

    The NLS judges each observation in its own camera's pixels; with one scale for all, the
    BA started near 9 px and, with the loops split in two, crawled to its iteration cap.
    Near-collinear features whose noise-level theta-bar put them behind later cameras of the
    street started the BA on the saddle of flipped rays, where the iterations it spent and
    where it stopped moved with the rounding of the BLAS pool and the chunking. From
    infinity it converges in the same few steps on each.
    """
    code = _MIXED_FOCAL.replace('sys.argv[1]', repr(blas)).replace('sys.argv[2]', repr(threads))
    run_python(code)
