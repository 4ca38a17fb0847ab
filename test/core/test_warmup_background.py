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
"""A first compilation in the background: 'auto' is the numpy engine until it is done.

The compilation itself is stood in for (it takes tens of seconds; the node test that runs a
fresh colcon install compiles for real): what is checked is which engine runs meanwhile,
after, and after a failure.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
import threading

from pmba_ros.core import engine, jit, warmup
import pytest

pytestmark = pytest.mark.skipif(not engine.compiled_available(), reason='numba not installed')


@dataclass
class Compilation:
    """The stand-in compilation: it ends once ``gate`` is set, failing if ``fail``."""

    gate: threading.Event = field(default_factory=threading.Event)
    fail: bool = False

    def warm_up(self) -> float:
        """Return 1.5 s once released, or raise as a numba error would."""
        assert self.gate.wait(30.0)
        if self.fail:
            msg = 'a numba error'
            raise RuntimeError(msg)
        return 1.5


@pytest.fixture
def compilation(monkeypatch: pytest.MonkeyPatch) -> Iterator[Compilation]:
    """Stand in for warm_up; leave the engine as it was."""
    stand_in = Compilation()
    monkeypatch.setattr(warmup, 'compile_in_child', lambda: True)
    monkeypatch.setattr(warmup, 'warm_up', stand_in.warm_up)
    yield stand_in
    jit.NOT_READY.clear()


def test_auto_is_numpy_while_compiling_then_compiled(compilation: Compilation) -> None:
    """Meanwhile 'auto' (and the window's gathering) run numpy; 'compiled' by name still can."""
    got: list[float | None] = []
    thread = warmup.warm_up_in_background(got.append)
    assert engine.resolve('auto') is engine.NUMPY and not engine.compiled_ready()
    assert engine.resolve('compiled') is engine.COMPILED
    compilation.gate.set()
    thread.join(30.0)
    assert got and got[0] is not None and got[0] >= 0.0
    assert engine.resolve('auto') is engine.COMPILED and engine.compiled_ready()


def test_a_failed_compilation_leaves_the_numpy_engine(compilation: Compilation,
                                                      caplog: pytest.LogCaptureFixture) -> None:
    """The failure is logged, ``done`` gets None, and 'auto' stays numpy."""
    got: list[float | None] = []
    compilation.fail = True
    thread = warmup.warm_up_in_background(got.append)
    compilation.gate.set()
    thread.join(30.0)
    assert got == [None]
    assert engine.resolve('auto') is engine.NUMPY
    assert 'compiling the solver loops failed' in caplog.text


def test_a_run_whose_engine_turns_compiled_midway_matches_a_compiled_run() -> None:
    """The back-end solving with numpy, then with the compiled loops from keyframe 30 on.

    As in a node whose compilation ends during the run: same keyframes, no error, the poses
    as a compiled run's within the engines' rounding differences (they are tested to agree).
    """
    from pmba_ros.backend.config import BackendConfig
    from pmba_ros.backend.logic import BackendLogic
    from pmba_ros.backend.msg_backend import RosbagsBackend
    from pmba_ros.sim.sequence import simulate_sequence

    from ..backend.test_logic import camera_info_msg, keyframe_msg, tracks_msg

    seq = simulate_sequence('street', n_keyframes=60, seed=4)
    runs = []
    for switch in (0, 30):
        logic = BackendLogic(BackendConfig(deterministic=True), RosbagsBackend())
        logic.on_camera_info(camera_info_msg(seq))
        try:
            for i in range(len(seq)):
                if i < switch:
                    jit.NOT_READY.set()
                else:
                    jit.NOT_READY.clear()
                logic.on_tracks(tracks_msg(seq, i))
                logic.on_keyframe(keyframe_msg(seq, i))
                logic.step()
        finally:
            jit.NOT_READY.clear()
        assert not logic.stats.counters['internal_errors']
        runs.append(logic.optimized_trajectory().positions_xyz)
    assert runs[0].shape == runs[1].shape == (60, 3)
    assert float(abs(runs[0] - runs[1]).max()) < 1e-9


def test_a_child_that_fails_to_compile_is_a_warning(monkeypatch: pytest.MonkeyPatch,
                                                    caplog: pytest.LogCaptureFixture) -> None:
    """The child's exit code and error output are logged; the caller then compiles itself."""
    import sys

    monkeypatch.setattr(sys, 'executable', '/bin/false')
    assert not warmup.compile_in_child()
    assert 'failed (exit code 1)' in caplog.text
