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
"""The numba switch and cache (pmba_ros.core.jit), in fresh processes on a copy of the package."""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import subprocess
import sys

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / 'pmba_ros'

_SOLVE = """
import sys
from pmba_ros.core import jit
from pmba_ros.core.compiled import loss
from pmba_ros.core.engine import compiled_available
from pmba_ros.core.solve import SolveOptions, solve
from pmba_ros.sim.scenes import street_scene
scene = street_scene(seed=0, n_cams=6, n_points=40)
result = solve(scene.start, SolveOptions(max_iterations=3))
assert result.final_rms_px < result.initial_rms_px, result.summary()
assert loss.__file__.startswith(sys.argv[1]), loss.__file__
hits = sum(loss._robust_cost.stats.cache_hits.values()) if compiled_available() else 0
print('numba' in sys.modules, compiled_available(), jit.CACHING, hits)
"""


# One compiled loop stands for all of them: they share the cache folder.
_LOOP = """
import sys
import numpy as np
from pmba_ros.core import jit
from pmba_ros.core.compiled import loss
from pmba_ros.core.engine import compiled_available
assert loss.__file__.startswith(sys.argv[1]), loss.__file__
assert loss.robust_cost(np.array([[0.5, 3.0]]), 'cauchy', 1.0) > 0.0
hits = sum(loss._robust_cost.stats.cache_hits.values()) if compiled_available() else 0
print('numba' in sys.modules, compiled_available(), jit.CACHING, hits)
"""


def _copy_package(root: Path) -> Path:
    """Copy pmba_ros under ``root`` with no __pycache__ folder it could write to."""
    dest = root / 'site' / 'pmba_ros'
    shutil.copytree(PACKAGE, dest, ignore=shutil.ignore_patterns('__pycache__'))
    # A file where numba's in-tree cache folder would go: not writable even for root.
    (dest / 'core' / 'compiled' / '__pycache__').write_text('')
    return dest


def _run(site: Path, env: dict[str, str], probe: str = _SOLVE) -> tuple[list[str], str]:
    """Run ``probe`` (a small solve) with the copy; return its words and stderr."""
    base = {k: v for k, v in os.environ.items()
            if k not in ('NUMBA_CACHE_DIR', 'XDG_CACHE_HOME', 'PMBA_NUMBA')}
    proc = subprocess.run([sys.executable, '-c', probe, str(site)], capture_output=True,
                          text=True, timeout=900, check=False, cwd=site.parent,
                          env={**base, 'PYTHONPATH': str(site.parent), **env})
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.split(), proc.stderr


def test_read_only_install_without_home_caches_in_a_private_temp_folder(
        tmp_path: Path) -> None:
    """No writable package folder or home: one warning, loops cached in a temp folder."""
    pytest.importorskip('numba')
    site = _copy_package(tmp_path)
    blocked = tmp_path / 'blocked'
    blocked.write_text('')
    tmp = tmp_path / 'tmp'
    tmp.mkdir()
    env = {'HOME': str(blocked / 'home'), 'TMPDIR': str(tmp)}
    words, err = _run(site, env, _LOOP)
    assert words == ['True', 'True', 'True', '0'], (words, err)
    cache = tmp / f'pmba_ros-numba-{os.getuid()}'
    assert f'compiled solver loops are cached in {cache}' in err
    assert err.count('CacheWarning') == 1, err
    assert any(cache.rglob('*.nbi')), 'no numba index written'
    assert (cache.stat().st_mode & 0o077) == 0, 'cache folder readable by others'
    # The second process loads the loops and says nothing.
    words, err = _run(site, env, _LOOP)
    assert int(words[3]) > 0, 'the second process compiled again'
    assert 'Warning' not in err, err


def test_cache_folder_of_another_user_is_refused(tmp_path: Path) -> None:
    """A shared, group-writable cache folder is not trusted; the user cache is used."""
    pytest.importorskip('numba')
    from pmba_ros.core import jit

    shared = tmp_path / 'shared'
    shared.mkdir(mode=0o777)
    shared.chmod(0o777)
    assert not jit._private_dir(shared)
    own = tmp_path / 'own'
    assert jit._private_dir(own)
    assert (own.stat().st_mode & 0o777) == 0o700


def test_pmba_numba_0_never_imports_numba(tmp_path: Path) -> None:
    """PMBA_NUMBA=0: the package imports and solves on numpy, numba stays unloaded."""
    site = _copy_package(tmp_path)
    words, err = _run(site, {'PMBA_NUMBA': '0'})
    assert words[:3] == ['False', 'False', 'False'], (words, err)
    assert 'Warning' not in err, err


def test_no_writable_folder_anywhere_compiles_in_memory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Nowhere to write: caching off (numba would refuse to decorate), said in a warning."""
    from types import SimpleNamespace

    from pmba_ros.core import jit

    blocked = tmp_path / 'blocked'
    blocked.write_text('')
    monkeypatch.delenv('NUMBA_CACHE_DIR', raising=False)
    monkeypatch.setattr(jit, 'SOURCE_DIR', blocked / 'core')
    monkeypatch.setattr(jit, 'user_cache_dirs', lambda: iter([blocked / 'a', blocked / 'b']))
    config = SimpleNamespace(CACHE_DIR='')
    with pytest.warns(jit.CacheWarning, match='compiled again in every process'):
        assert jit.choose_cache(SimpleNamespace(config=config)) is False
    assert config.CACHE_DIR == ''
