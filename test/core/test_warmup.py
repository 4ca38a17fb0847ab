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
"""The warm-up compiles every loop the solver, the back-end and the replay use, once."""

from __future__ import annotations

from pathlib import Path

from pmba_ros.core import engine, jit, warmup
import pytest

from ..conftest import run_python


def test_warm_up_without_compiled_loops_does_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    """With the loops off there is nothing to wait for."""
    monkeypatch.setattr(engine, 'compiled_available', lambda: False)
    monkeypatch.setattr(warmup, 'compiled_available', lambda: False)
    assert warmup.warm_up() == 0.0
    assert warmup.is_warm()


def test_warm_up_leaves_nothing_to_compile_for_solves_and_a_replay() -> None:
    """In a fresh process: after warm_up, no solve of any kind and no replay compiles a loop.

    A dispatcher lists a signature once it compiled or loaded a loop, so new signatures
    after the warm-up would be compilations inside the user's first keyframe.
    """
    pytest.importorskip('numba')
    run_python(
        'import tempfile\n'
        'from pathlib import Path\n'
        'from numba.core.registry import CPUDispatcher\n'
        'import pmba_ros.core.compiled.anchor_search, pmba_ros.core.compiled.assembly\n'
        'import pmba_ros.core.compiled.camera, pmba_ros.core.compiled.loss\n'
        'import pmba_ros.core.compiled.residuals, pmba_ros.core.compiled.schur\n'
        'import pmba_ros.core.compiled.linear_rays, pmba_ros.core.compiled.epipolar\n'
        'import pmba_ros.core.compiled.gather\n'
        'from pmba_ros.core import compiled, warmup\n'
        'def signatures():\n'
        '    return {n: len(d.signatures) for m in (compiled.anchor_search, compiled.assembly,\n'
        '            compiled.camera, compiled.loss, compiled.residuals, compiled.schur,\n'
        '            compiled.linear_rays, compiled.epipolar, compiled.gather)\n'
        '            for n, d in vars(m).items() if isinstance(d, CPUDispatcher)}\n'
        'assert not any(signatures().values())\n'
        'assert warmup.warm_up() > 0.0\n'
        'after = signatures()\n'
        'for name in ("_pmba_rays", "_pmba_rows", "_assemble", "_reduce", "_widest_pairs",\n'
        '             "_robust_cost", "_sphere_retract", "_projection_jacobian",\n'
        '             "_ray_normal_matrix", "_ray_errors", "_nls_weights", "_ray_gradient",\n'
        '             "_epipolar_votes", "_rotation_covariances", "_median_angles",\n'
        '             "_epipolar_outer", "_translation_votes", "_linear_rays", "_ray_depths",\n'
        '             "_cheirality_row_norms", "_point_features", "_ordered_tracks",\n'
        '             "_anchors"):\n'
        '    assert after[name], name\n'
        'from pmba_ros.core.solve import SolveOptions, solve\n'
        'from pmba_ros.sim.scenes import street_scene\n'
        'scene = street_scene(seed=1, n_cams=8, n_points=60)\n'
        'for param in ("pmba", "xyz", "idp"):\n'
        '    for solver in ("dogleg", "lm", "gn"):\n'
        '        for loss in ("none", "cauchy", "huber"):\n'
        '            solve(scene.start, SolveOptions(param=param, solver=solver, loss=loss,\n'
        '                                            max_iterations=3))\n'
        'from pmba_ros.backend.config import BackendConfig\n'
        'from pmba_ros.replay import replay\n'
        'from pmba_ros.sim.bag import write_sequence_bag\n'
        'from pmba_ros.sim.sequence import simulate_sequence\n'
        'tmp = Path(tempfile.mkdtemp())\n'
        'write_sequence_bag(simulate_sequence("street", n_keyframes=30, seed=0), tmp / "bag")\n'
        'replay([tmp / "bag"], tmp / "out", BackendConfig())\n'
        'grown = {n: (after[n], k) for n, k in signatures().items() if k != after[n]}\n'
        'assert not grown, grown\n')


def test_is_warm_follows_the_marker_in_the_cache_folder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Cold until a warm-up wrote its marker; no cache folder means never warm."""
    pytest.importorskip('numba')
    monkeypatch.setattr(jit, 'cache_folder', lambda: tmp_path)
    assert not warmup.is_warm()
    warmup.warm_up()
    assert warmup.is_warm()
    assert len(list(tmp_path.glob('pmba_warmup-*.ok'))) == 1
    monkeypatch.setattr(jit, 'cache_folder', lambda: None)
    assert not warmup.is_warm()
