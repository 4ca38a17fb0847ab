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
"""Replay plots (matplotlib, an optional extra imported only here, lazily).

Install with ``pip install 'pmba_ros[plot]'`` (or ``pip install matplotlib``). The Agg
backend is used, so no display is needed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import logging
from pathlib import Path
from typing import Any, TYPE_CHECKING

import numpy as np
from pmba_ros.errors import EvaluationError, PmbaError
from pmba_ros.io.atomic import write_atomic

if TYPE_CHECKING:
    from collections.abc import Sequence

    from numpy.typing import ArrayLike
    from pmba_ros.core.solve import IterationRecord
    from pmba_ros.eval.metrics import EvalResult
    from pmba_ros.eval.trajectory import Trajectory
    from pmba_ros.replay_report import ReplayReport

logger = logging.getLogger(__name__)

_DPI = 120


def pyplot() -> Any:
    """Import matplotlib's pyplot with the Agg backend (a file back end, no display).

    Raises:
        PmbaError: If matplotlib is not installed.
    """
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError as err:
        msg = ('--plot needs matplotlib, which is not installed; install it with '
               '"pip install \'pmba_ros[plot]\'" or "pip install matplotlib"')
        raise PmbaError(msg) from err
    return plt


def plot_top_view(path: Path, trajectories: Sequence[tuple[str, Trajectory]],
                  title: str = 'Keyframe trajectories (top view)') -> Path:
    """Plot x-y positions of several trajectories (already in one frame).

    Args:
        path: Output PNG.
        trajectories: ``(label, trajectory)`` pairs, drawn in order.
        title: Figure title.

    Returns:
        ``path``.

    Raises:
        PmbaError: If matplotlib is missing or the file cannot be written.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 6))
    styles = {'ground truth': ('k', '-', 2.0), 'front-end': ('tab:red', '--', 1.2),
              'optimized': ('tab:blue', '-', 1.2)}
    for label, traj in trajectories:
        color, line, width = styles.get(label, (None, '-', 1.0))
        xy = traj.positions_xyz
        ax.plot(xy[:, 0], xy[:, 1], color=color, linestyle=line, linewidth=width,
                label=f'{label} ({len(traj)})')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    ax.set_aspect('equal', adjustable='datalim')
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title(title)
    return _save(fig, plt, path)


def plot_series(path: Path, values: Sequence[float], ylabel: str, title: str, *,
                log_scale: bool = False, xlabel: str = 'solve') -> Path:
    """Plot one value per solve / keyframe.

    Args:
        path: Output PNG.
        values: The values (NaN entries are skipped).
        ylabel: Y axis label.
        title: Figure title.
        log_scale: Logarithmic y axis.
        xlabel: X axis label.

    Returns:
        ``path``.

    Raises:
        PmbaError: If matplotlib is missing or the file cannot be written.
    """
    return plot_curves(path, [('', values)], ylabel, title, log_scale=log_scale,
                       xlabel=xlabel)


def plot_curves(path: Path, curves: Sequence[tuple[str, ArrayLike]], ylabel: str,
                title: str, *, log_scale: bool = False, xlabel: str = 'keyframe') -> Path:
    """Plot several labelled series against their index.

    Args:
        path: Output PNG.
        curves: ``(label, values)`` pairs.
        ylabel: Y axis label.
        title: Figure title.
        log_scale: Logarithmic y axis.
        xlabel: X axis label.

    Returns:
        ``path``.

    Raises:
        PmbaError: If matplotlib is missing or the file cannot be written.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    colors = {'front-end': 'tab:red', 'optimized': 'tab:blue'}
    positive = False
    for label, values in curves:
        arr = np.asarray(values, dtype=np.float64)
        positive = positive or bool(np.any(arr > 0))
        ax.plot(np.arange(arr.shape[0]), arr, '.-', markersize=3, linewidth=0.8,
                color=colors.get(label), label=label or None)
    if log_scale and positive:
        ax.set_yscale('log')
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    if any(label for label, _ in curves):
        ax.legend()
    ax.set_title(title)
    return _save(fig, plt, path)


@dataclass
class ConvergenceTrace:
    """The pixel RMS of every iteration of a run's bundle adjustments, one after another.

    A global initialization can run its BA more than once (resumed with the tracks it had
    dropped, a result it may discard): each BA's clock restarts, so its times continue
    from the end of the one before.

    Attributes:
        times_s: Time of each record, the BAs one after another.
        rms_px: Pixel RMS of each record.
        ba_starts: Index of each BA's first record.
    """

    times_s: list[float] = field(default_factory=list)
    rms_px: list[float] = field(default_factory=list)
    ba_starts: list[int] = field(default_factory=list)
    _clock0: float = field(default=0.0, init=False, repr=False)   # the newest BA's start

    def add(self, record: IterationRecord) -> None:
        """Append a solver's iteration record (iteration 0: a BA starts)."""
        if record.iteration == 0 or not self.ba_starts:
            self._clock0 = self.times_s[-1] if self.times_s else 0.0
            self.ba_starts.append(len(self.times_s))
        self.times_s.append(self._clock0 + record.time_s)
        self.rms_px.append(record.rms_px)

    def bas(self) -> list[tuple[list[float], list[float]]]:
        """Return each BA's (times, pixel RMS)."""
        ends = [*self.ba_starts[1:], len(self.times_s)]
        return [(self.times_s[a:b], self.rms_px[a:b])
                for a, b in zip(self.ba_starts, ends, strict=True)]


def plot_convergence(path: Path, traces: Sequence[tuple[str, ConvergenceTrace, float]]) -> Path:
    """Plot each labelled run's pixel RMS over time; ``(label, trace, result's pixel RMS)``.

    A run of several BAs draws the later ones dashed and its result's RMS as a dotted line:
    its result need not be the last BA's (a resumed BA can be discarded).

    Raises:
        PmbaError: If matplotlib is missing or the file cannot be written.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, trace, result_rms in traces:
        bas = trace.bas()
        color = None
        for k, (times, rms) in enumerate(bas):
            legend = {0: label, 1: f'{label}: BA resumed'}.get(k)   # one entry per kind
            line, = ax.semilogy(times, rms, 'o-' if k == 0 else 's--', markersize=3,
                                color=color, label=legend)
            color = line.get_color()
        if len(bas) > 1:
            ax.axhline(result_rms, color=color, linestyle=':', linewidth=1,
                       label=f'{label}: result, {result_rms:.4f} px')
    ax.set_xlabel('time [s]')
    ax.set_ylabel('pixel RMS')
    ax.legend()
    ax.grid(True, which='both', alpha=0.3)
    return _save(fig, plt, path)


def _save(fig: Any, plt: Any, path: Path) -> Path:
    """Save and close a figure."""
    try:
        fig.tight_layout()
        write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=_DPI))
    except OSError as err:
        msg = f'{path}: cannot write plot: {err}'
        raise PmbaError(msg) from err
    finally:
        plt.close(fig)
    logger.debug('wrote %s', path)
    return path


def write_replay_plots(out: Path, frontend: Trajectory, optimized: Trajectory,
                       gt: Trajectory | None, report: ReplayReport,
                       align: str = 'sim3') -> dict[str, Path]:
    """Write the replay PNGs: top view, cost per solve, solve time per keyframe.

    With ground truth, both estimates are aligned onto it (``align``) for the top view.

    Returns:
        Plot name -> path.

    Raises:
        PmbaError: If matplotlib is missing or a file cannot be written.
    """
    curves: list[tuple[str, Trajectory]] = []
    errors: list[tuple[str, ArrayLike]] = []
    if gt is not None:
        from pmba_ros.eval.metrics import ate
        curves.append(('ground truth', gt))
        for label, traj in (('front-end', frontend), ('optimized', optimized)):
            try:
                result = ate(traj, gt, align=align)
            except EvaluationError:
                curves.append((label, traj))
                continue
            curves.append((label, _aligned(traj, result)))
            errors.append((label, result.errors))
    else:
        curves = [('front-end', frontend), ('optimized', optimized)]
    files = {'plot_top_view': plot_top_view(out / 'trajectories_top.png', curves)}
    if errors:
        files['plot_ate'] = plot_curves(out / 'ate_per_keyframe.png', errors,
                                        'position error (m)',
                                        f'ATE per keyframe ({align}-aligned)')
    files['plot_cost'] = plot_curves(out / 'cost_per_solve.png',
                                     [('before', report.costs_before),
                                      ('after', report.costs)],
                                     'cost', 'Cost per solve', log_scale=True,
                                     xlabel='solve')
    files['plot_solve_time'] = plot_series(out / 'solve_time.png', report.solve_ms,
                                           'solve time (ms)', 'Solve time per keyframe',
                                           xlabel='keyframe solve')
    return files


def _aligned(traj: Trajectory, result: EvalResult) -> Trajectory:
    """Return ``traj`` moved by the alignment of an ATE result."""
    from pmba_ros.eval.align import apply_alignment, UmeyamaResult
    fit = UmeyamaResult(result.rotation, result.translation, result.scale)
    return apply_alignment(traj, fit)


__all__ = ['plot_curves', 'plot_series', 'plot_top_view', 'write_replay_plots']
