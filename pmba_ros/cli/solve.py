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
"""``pmba solve``: solve a BA problem file or a simulated scene and report convergence.

Usage examples::

    pmba solve sim:street                         # PMBA-Dogleg on a simulated street
    pmba solve sim:street --compare               # PMBA-DL vs XYZ-LM vs IDP-LM, one table
    pmba solve problem-49-7776-pre.txt --param xyz --solver lm --report r.json
    pmba solve problem-16-22106-pre.txt.bz2       # as downloaded from the BAL site
    pmba solve fake-pile/ --format parallaxba --init global --out result/
    pmba solve colmap/sparse/0 --init global --out refined/   # writes a COLMAP model too
    pmba solve bundle/bundle.out --out refined/                # writes refined/bundle.out
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import math
from pathlib import Path
import sys
from typing import Any, TYPE_CHECKING

import numpy as np
from pmba_ros._json import dumps_report
from pmba_ros.cli.argtypes import non_negative_int, positive_float, positive_int
from pmba_ros.cli.progress import iteration_printer, stage_printer
from pmba_ros.core import so3
from pmba_ros.core.compiled import chunks
from pmba_ros.core.gauge import camera_components
from pmba_ros.core.loss import Loss
from pmba_ros.core.problem import BAProblem, Parameterization
from pmba_ros.core.solve import IterationRecord, solve, SolveOptions, SolveResult, SolverKind
from pmba_ros.errors import FormatError
from pmba_ros.io.atomic import atomic_open, prepare_output, write_text_atomic
from pmba_ros.io.text import detect_problem_format, file_bytes, plain_name
from pmba_ros.plot import ConvergenceTrace, plot_convergence, pyplot

if TYPE_CHECKING:
    from pmba_ros.cli.colmap_rigs import RigModel

#: ``--compare`` runs the paper's Table 4 pairing: PMBA with Dogleg, the baselines with LM.
COMPARE = (('pmba', 'dogleg'), ('xyz', 'lm'), ('idp', 'lm'))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the ``solve`` options."""
    parser.add_argument('problem', help='BAL file, ParallaxBA directory / Cam file, COLMAP '
                        'model directory (multi-camera rigs held rigid), Bundler .out file, or '
                        'sim:street[:SEED] / sim:table3[:SEED] / sim:large[:SEED]; files may '
                        'be bzip2, gzip or xz compressed, as the BAL collections are published')
    parser.add_argument('--format', choices=['auto', 'bal', 'parallaxba', 'colmap', 'bundler'],
                        default='auto', help='auto: a directory with cameras.txt/.bin is a '
                        'COLMAP model, a .out file a Bundler file; with --out their refined '
                        'model is written there too, in the same format')
    parser.add_argument('--param', choices=['pmba', 'xyz', 'idp'], default='pmba',
                        help='feature parameterization: parallax angle (PMBA), Euclidean '
                        'points (XYZ) or inverse depth (IDP)')
    parser.add_argument('--solver', choices=['dogleg', 'lm', 'gn'], default='dogleg',
                        help='Powell dogleg, Levenberg-Marquardt or Gauss-Newton')
    parser.add_argument('--loss', choices=['none', 'huber', 'cauchy'], default='none',
                        help='robust loss on the residuals (none: least squares)')
    parser.add_argument('--loss-scale', type=positive_float, default=2.0,
                        help='loss scale in pixels')
    parser.add_argument('--max-iters', type=non_negative_int, default=100,
                        help='iteration budget of each solve')
    parser.add_argument('--engine', choices=['auto', 'numpy', 'compiled'], default='auto',
                        help='numerical engine: numpy, the compiled numba loops, or auto '
                        '(compiled where numba is installed and PMBA_NUMBA is not 0); '
                        'both give the same iterates to rounding')
    parser.add_argument('--threads', type=positive_int, default=None,
                        help='most threads for the compiled loops of a large problem '
                        '(default: every core this process may use)')
    parser.add_argument('--init', choices=['file', 'global'], default='file',
                        help="start from the file's poses and points, or run PMBA's global "
                        'initialization from the tracks alone')
    parser.add_argument('--paper-error', action='store_true',
                        help="PMBA: the paper's isotropic chordal ray error instead of the "
                        'pixel-weighted one')
    parser.add_argument('--compare', action='store_true',
                        help='run PMBA-Dogleg, XYZ-LM and IDP-LM from the same file and print '
                        "one table; rms0 is each method's pixel RMS at its own start, which "
                        'for PMBA can be lower: points behind their main anchor are '
                        're-initialized from the rotations')
    parser.add_argument('--report', type=Path, help='write a JSON report here')
    parser.add_argument('--out', type=Path, help='write poses (TUM: the input camera index '
                        'as stamp), points (x y z and the input point id per line, points at '
                        'infinity left out) and report here')
    parser.add_argument('--plot', action='store_true', help='with --out: convergence.png')
    parser.add_argument('--quiet', action='store_true',
                        help='no progress lines on stderr (per iteration: cost, pixel RMS, '
                        'trust-region radius, elapsed time, step outcome; with --init global '
                        'also each stage as it ends)')


def load_problem(spec: str, fmt: str = 'auto') -> BAProblem:
    """Load a problem from a file, a ParallaxBA directory or a ``sim:`` scene name.

    Raises:
        FormatError: If the format cannot be told or the file is malformed.
    """
    if spec.startswith('sim:'):
        from pmba_ros.sim import scenes
        name, _, seed_text = spec[4:].partition(':')
        seed = _seed(spec, seed_text)
        makers: dict[str, Callable[..., scenes.SimScene]] = {
            'street': scenes.street_scene, 'table3': scenes.table3_scene,
            'large': scenes.synthetic_large}
        if name not in makers:
            msg = f'unknown simulated scene {name!r}; choose one of {sorted(makers)}'
            raise FormatError(msg)
        return makers[name](seed=seed).start
    path = Path(spec)
    if not path.exists():
        msg = f'{path}: no such file or directory'
        raise FormatError(msg)
    if fmt == 'auto':
        fmt = _detect_format(path)
    if fmt == 'colmap':
        from pmba_ros.io.colmap import read_colmap, to_problem
        return to_problem(read_colmap(path))[0]
    if fmt == 'bundler':
        from pmba_ros.io import bundler
        return bundler.to_problem(bundler.read_bundler(path))[0]
    if fmt == 'bal':
        from pmba_ros.io.bal import read_bal
        return read_bal(path)
    from pmba_ros.io.parallaxba_files import read_parallaxba, triangulate_points
    problem = read_parallaxba(path)
    if problem.points_w is None:
        problem = problem.with_points(triangulate_points(problem))
    return problem


def _seed(spec: str, text: str) -> int:
    """Return the seed of a ``sim:NAME:SEED`` spec (0 if absent).

    Raises:
        FormatError: If the seed is not a non-negative integer.
    """
    if not text:
        return 0
    if not text.isdigit():
        msg = f'{spec!r}: the seed after the scene name must be an integer >= 0, got {text!r}'
        raise FormatError(msg)
    return int(text)


def _check_outputs(args: argparse.Namespace) -> None:
    """Fail before the solve if ``--out`` or ``--report`` cannot be written.

    A missing ``--report`` folder is created and written in once
    (:func:`~pmba_ros.io.atomic.prepare_output`), so the result of a long solve is not lost.

    Raises:
        PmbaError: If ``--out`` is an existing file, ``--report`` cannot be written (a
            folder, in a folder that takes no file), or ``--plot`` lacks ``--out`` or
            matplotlib.
        OSError: If the ``--out`` folder cannot be created.
    """
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        msg = f'--out {args.out}: exists and is not a folder'
        raise FormatError(msg)
    if args.report is not None:
        prepare_output(args.report, '--report')
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
    if args.plot:
        if args.out is None:
            msg = '--plot writes convergence.png into --out; give --out'
            raise FormatError(msg)
        pyplot()


def _options(param: str, solver: str, args: argparse.Namespace) -> SolveOptions:
    """Return the solve options of one run.

    Raises:
        FormatError: If an option value is invalid.
    """
    try:
        return SolveOptions(param=Parameterization(param), solver=SolverKind(solver),
                            loss=Loss(args.loss), loss_scale_px=args.loss_scale,
                            max_iterations=args.max_iters, pixel_weighted=not args.paper_error,
                            engine=args.engine)
    except ValueError as err:
        msg = f'invalid solver options: {err}'
        raise FormatError(msg) from err


def _detect_format(path: Path) -> str:
    """Tell a COLMAP model, a Bundler file, a BAL file and a ParallaxBA set by their content."""
    from pmba_ros.io.colmap import is_colmap_model
    if is_colmap_model(path):
        return 'colmap'
    if path.is_file() and file_bytes(path, 64).lstrip().startswith(b'# Bundle file'):
        return 'bundler'
    # Bundler's header line is optional; without it only the name tells it from BAL.
    return 'bundler' if plain_name(path).endswith('.out') else detect_problem_format(path)


def _write_model(out: Path, source: Path, fmt: str, problem: BAProblem, result: SolveResult,
                 init: Any | None) -> None:
    """Write the refined model in its input format (COLMAP text / binary, Bundler) to ``out``.

    The solution is first brought onto the model's frame
    (:func:`~pmba_ros.io.solution_frame.in_model_frame`), so the model is refined in place.
    """
    from pmba_ros.io import bundler, colmap
    from pmba_ros.io.solution_frame import in_model_frame
    if init is None:
        cams = np.arange(problem.n_cams)
        rows = np.argsort(problem.feature_ids)[np.searchsorted(
            np.sort(problem.feature_ids), result.problem.feature_ids)]
    else:
        cams = init.camera_index
        rows = init.feature_index
    point_ids = problem.feature_ids[rows]
    assert problem.points_w is not None  # both formats store their points
    # Bundler projects like a pinhole, which does not tell a ray from its opposite.
    R_wc, centers, points = in_model_frame(result, problem.R_wc[cams], problem.centers_w[cams],
                                           problem.points_w[rows], behind=fmt == 'bundler')
    if fmt == 'colmap':
        model = colmap.read_colmap(source)
        _, image_ids = colmap.to_problem(model)
        refined = colmap.updated(model, image_ids[cams], R_wc, centers, point_ids, points)
        colmap.write_colmap(out, refined, binary=(source / 'cameras.bin').is_file())
    else:
        b_model = bundler.read_bundler(source)
        _, file_cams = bundler.to_problem(b_model)
        b_refined = bundler.updated(b_model, file_cams[cams], R_wc, centers, point_ids, points)
        bundler.write_bundler(out / plain_name(source), b_refined)


def _recorder(trace: ConvergenceTrace, show: Callable[[IterationRecord], None] | None,
              ) -> Callable[[IterationRecord], None]:
    """Return a callback adding every iteration to ``trace`` (and showing it, if given)."""
    def record(rec: IterationRecord) -> None:
        trace.add(rec)
        if show is not None:
            show(rec)
    return record


def run(args: argparse.Namespace) -> int:
    """Run ``pmba solve``."""
    if args.init == 'global' and (args.compare or args.param != 'pmba'):
        # The initialization's own BA is the result, and it needs parallax features.
        msg = (f"--init global ends in PMBA's bundle adjustment: it takes --param pmba (any "
               f"--solver), not {'--compare' if args.compare else '--param ' + args.param}; "
               "compare the parameterizations from the file's start with --init file")
        raise FormatError(msg)
    _check_outputs(args)
    chunks.set_max_threads(args.threads)
    rigs = _load_rigs(args)
    problem = rigs.problem if rigs is not None else load_problem(args.problem, args.format)
    if rigs is not None and rigs.held:
        print(f'{rigs.rigs.frames_path}: one pose per frame, {len(rigs.problem.rig or [])} '
              'rig cameras held rigid')
    print(f'{args.problem}: {problem.n_cams} cameras, {problem.n_feats} features, '
          f'{problem.n_obs} observations' + (f', dropped {problem.dropped}' if problem.dropped
                                             else ''))
    runs: tuple[tuple[str, str], ...] = COMPARE if args.compare else ((args.param, args.solver),)
    results: list[SolveResult] = []
    inits: list[Any] = []
    report: dict[str, Any] = {}
    traces: list[ConvergenceTrace] = []
    for param, solver in runs:
        resumed = ''
        options = _options(param, solver, args)
        traces.append(ConvergenceTrace())
        callback = _recorder(traces[-1], None if args.quiet
                             else iteration_printer(f'{param}-{solver}'))
        progress = None if args.quiet else stage_printer()
        if args.init == 'global' and rigs is not None and rigs.held:
            from pmba_ros.cli.colmap_rigs import global_rig_init
            init: Any = global_rig_init(rigs, options, callback, progress)
            result = init.solve
            entry = {**result.to_report(), 'init': init.to_report(),
                     'ba_invocations': init.ba_invocations}
            inits.append(init)
        elif args.init == 'global':
            from pmba_ros.init.pipeline import global_init, InitOptions
            init = global_init(problem, InitOptions(solve_options=options), progress=progress,
                               callback=callback)
            resumed = _resumed(init.report) if init.ba_invocations > 1 else ''
            result = init.solve
            entry = {**result.to_report(), 'init': init.to_report(),
                     'ba_invocations': init.ba_invocations}
            inits.append(init)
        else:
            result = solve(problem, options, callback=callback)
            entry = {**result.to_report(), 'ba_invocations': 1}
            inits.append(None)
        results.append(result)
        report[f'{param}-{solver}'] = entry
        if not args.compare:
            print(result.summary())
            if resumed:
                print(resumed)
    if args.compare:
        print(_table(results))
    if args.init != 'global':
        _warn_components(problem, report)
        _warn_behind(problem, report, args.loss)
    else:
        _warn_left_out(problem, inits[0], report)
    _warn_focal_lengths(problem, report)
    for r in results:
        if not r.converged:
            print(f'warning: {r.options.param.value}-{r.options.solver.value} stopped at '
                  f'{r.termination.value} after {r.iterations} iterations, not converged '
                  f'(final rms {r.final_rms_px:.4f} px): the result is not a minimum',
                  file=sys.stderr)
        elif text := r.misfit():
            _warn(report, f'{r.options.param.value}-{r.options.solver.value}: {text}')
    for text in [] if rigs is None else rigs.warnings:
        _warn(report, text)
    out_report: dict[str, Any] = report if args.compare else next(iter(report.values()))
    _warn_non_finite(results, out_report)
    if args.report:
        write_text_atomic(args.report, dumps_report(out_report))
    if args.out:
        _write_outputs(args.out, results, out_report, traces if args.plot else None,
                       [None if i is None else i.camera_index for i in inits])
        source = Path(args.problem)
        fmt = args.format
        if fmt == 'auto' and not args.problem.startswith('sim:'):
            fmt = _detect_format(source)
        if not args.compare and fmt in ('colmap', 'bundler'):
            for text in _write_solved_model(args.out, source, fmt, problem, results[0],
                                            inits[0], rigs):
                print(f'warning: {text}', file=sys.stderr)
    return 0


def _load_rigs(args: argparse.Namespace) -> RigModel | None:
    """Return a COLMAP model's rigs and frames (a ``RigModel``), or None without them.

    Raises:
        FormatError: If the rigs or frames are malformed.
    """
    path = Path(args.problem)
    if args.problem.startswith('sim:') or not path.exists() or args.format not in (
            'auto', 'colmap') or (args.format == 'auto' and _detect_format(path) != 'colmap'):
        return None
    from pmba_ros.cli.colmap_rigs import load_rig_model
    return load_rig_model(path, rigid=args.param == 'pmba' and not args.compare)


def _write_solved_model(out: Path, source: Path, fmt: str, problem: BAProblem,
                        result: SolveResult, init: Any | None, rigs: RigModel | None) -> list[str]:
    """Write the refined model in its format, a COLMAP model with its rigs and frames.

    Returns:
        Warnings: files of another COLMAP model left in the input's own folder.
    """
    from pmba_ros.cli import colmap_rigs
    if rigs is not None and rigs.held:
        colmap_rigs.write_rig_model(out, source, rigs, result,
                                    None if init is None else init.camera_index)
    else:
        _write_model(out, source, fmt, problem, result, init)
        if rigs is not None and rigs.written:
            colmap_rigs.write_frames_of_images(out, source, rigs)
    if fmt != 'colmap':
        return []
    with_rigs = rigs is not None and (rigs.held or rigs.written)
    return _clear_stale_colmap_files(out, source, with_rigs)


COLMAP_FILES = tuple(f'{name}.{form}' for name in ('cameras', 'images', 'points3D', 'rigs',
                                                   'frames') for form in ('bin', 'txt'))
"""The files of a COLMAP model, in either form."""


def _clear_stale_colmap_files(out: Path, source: Path, with_rigs: bool) -> list[str]:
    """Remove the COLMAP files in ``out`` that the model just written there does not have.

    COLMAP reads the binary form where both are there, and rigs and frames beside any model:
    an earlier run's files would be read instead of the refined model, or with it. In the
    input's own folder nothing is removed; a warning names them instead.
    """
    form = 'bin' if (source / 'cameras.bin').is_file() else 'txt'
    names = ('cameras', 'images', 'points3D') + (('rigs', 'frames') if with_rigs else ())
    written = {f'{name}.{form}' for name in names}
    stale = [out / f for f in COLMAP_FILES if f not in written and (out / f).is_file()]
    if not stale:
        return []
    listed = ', '.join(p.name for p in stale)
    if out.resolve() == source.resolve():
        msg = (f'{out} also holds {listed} of another model, which COLMAP may read instead '
               'of (or with) the refined one')
        return [msg]
    for path in stale:
        path.unlink()
    print(f'{out}: removed {listed} of an earlier model')
    return []


def _table(results: list[SolveResult]) -> str:
    """Return the ``--compare`` table, with a note when the methods start differently."""
    head = (f'{"method":<14}{"iters":>7}{"solves":>8}{"rms0 px":>10}{"rms px":>10}'
            f'{"cost":>14}{"time s":>9}{"s/iter":>8}  converged')
    rows = [head, '-' * len(head)]
    for r in results:
        label = f'{r.options.param.value.upper()}-{r.options.solver.value}'
        per_it = r.time_s / max(r.iterations, 1)
        rows.append(f'{label:<14}{r.iterations:>7}{r.linear_solves:>8}'
                    f'{r.initial_rms_px:>10.4f}{r.final_rms_px:>10.4f}{r.final_cost:>14.6e}'
                    f'{r.time_s:>9.2f}{per_it:>8.3f}  {r.converged}')
    rows.append('rms0 / rms: pixel reprojection RMS at the start / at the end; solves: '
                'linear solves')
    starts = {round(r.initial_rms_px, 4) for r in results}
    if len(starts) > 1:
        rows.append("rms0 differs between methods: each starts from the file's points in its "
                    'own parameterization, and PMBA re-initializes points behind their main '
                    'anchor from the rotations')
    return '\n'.join(rows)


def _write_outputs(out: Path, results: list[SolveResult], report: dict[str, Any],
                   traces: list[ConvergenceTrace] | None,
                   camera_index: list[np.ndarray | None]) -> None:
    """Write TUM poses, points, the plot and the report of each result into ``out``.

    ``traces`` holds each result's iterations for ``convergence.png`` (None: no plot);
    ``camera_index``, per result, the input camera of each solved camera (None: the
    cameras are the input's, in order).
    """
    out.mkdir(parents=True, exist_ok=True)
    for r, index in zip(results, camera_index, strict=True):
        stem = f'{r.options.param.value}_{r.options.solver.value}'
        q = so3.to_quat_xyzw(r.R_wc)
        # TUM files need stamps: a problem file has none, so the input camera index stands
        # in. A global initialization solves a subset (the largest view-graph component):
        # numbering its cameras 0.. would label each pose with another camera's index.
        stamps = np.arange(r.R_wc.shape[0]) if index is None else np.asarray(index)
        rows = np.column_stack([stamps.astype(float), r.centers_w, q])
        finite = np.all(np.isfinite(r.points_w), axis=1)
        with atomic_open(out / f'poses_{stem}.tum') as fh:
            np.savetxt(fh, rows, fmt='%.9g')
        # The ids tie each row to its input point: rows at infinity are left out.
        with atomic_open(out / f'points_{stem}.xyz') as fh:
            np.savetxt(fh, np.column_stack([r.points_w[finite], r.problem.feature_ids[finite]]),
                       fmt=['%.9g'] * 3 + ['%d'])
    if traces is not None:
        plot_convergence(out / 'convergence.png', [
            (f'{r.options.param.value.upper()}-{r.options.solver.value}', trace,
             r.final_rms_px) for r, trace in zip(results, traces, strict=True)])
    # The report goes last: its presence says the other outputs are complete.
    write_text_atomic(out / 'report.json', dumps_report(report))


def _warn_components(problem: BAProblem, report: dict[str, Any]) -> None:
    """Warn when no feature joins some of the cameras to the others (a gauge each)."""
    n, groups = camera_components(problem.n_cams, problem.obs.cam_idx, problem.obs.feat_idx,
                                  problem.n_feats)
    if n < 2:
        return
    sizes = np.bincount(groups).tolist()
    text = (f'the cameras form {n} groups that share no feature ({sizes} cameras): each was '
            "solved on its own, their relative pose and scale are the file's start's")
    _warn(report, text)


def _warn_left_out(problem: BAProblem, init: Any, report: dict[str, Any]) -> None:
    """Warn about cameras a global initialization could not place (so did not solve).

    Also when most image pairs had no baseline: the cameras then hang on the few that had.
    """
    left = problem.n_cams - init.camera_index.shape[0]
    if left > 0:
        _warn(report, f'global initialization: {left} of {problem.n_cams} cameras could not be '
              'placed (outside the largest group of views joined by two-view geometry, or '
              "without enough features; the report's init says which) and were not solved; "
              'a written model keeps them as read')
    pairs = init.to_report()['pairs']   # an InitResult's or a rig initialization's
    still = pairs['pairs_rejected']['low_parallax']
    if still > pairs['pairs_found']:
        _warn(report, f'global initialization: {still} of {pairs["pairs_candidate"]} image pairs '
              'show no baseline (the camera turned in place between them, as for a panorama): '
              f'the cameras were placed from the {pairs["pairs_found"]} pairs with one, and '
              'their positions are only as good as those baselines')


def _resumed(init_report: dict[str, Any]) -> str:
    """Return the line saying that the initialization's BA was resumed, and why."""
    ba, summary = init_report['ba'], init_report['summary']
    why = []
    if summary['inconsistent_tracks']:
        why.append(f'to try the {summary["inconsistent_tracks"]} tracks dropped before it '
                   f'again: {summary["tracks_readmitted"]} taken back')
    if ba.get('observations_off_after_ba'):
        why.append(f'without the {ba["observations_off_after_ba"]} observations it left far off')
    return (f'  global initialization: the BA above is the last of {summary["ba_invocations"]}'
            f' ({ba["iterations"]} iterations in all), resumed {" and ".join(why)}')


def _warn_behind(problem: BAProblem, report: dict[str, Any], loss: str) -> None:
    """Warn of observations whose point (the file's) is behind the camera that sees it.

    A pinhole reprojection (XYZ) fits them, since it does not tell a ray from its opposite;
    PMBA's ray errors cannot (a camera does not see behind itself), so without a robust loss
    a few of them hold the whole solve.
    """
    if problem.points_w is None:
        return
    obs = problem.obs
    with np.errstate(invalid='ignore'):
        depth = np.einsum('kj,kj->k', problem.R_wc[obs.cam_idx][:, :, 2],
                          problem.points_w[obs.feat_idx] - problem.centers_w[obs.cam_idx])
    behind = int(np.count_nonzero(depth < 0))
    if behind:
        hint = ('; --loss cauchy weighs them down' if loss == 'none' else '')
        _warn(report, f'{behind} observations see their point behind the camera in the file '
              "(wrong matches?): PMBA's ray errors cannot fit them as a pinhole reprojection "
              f'does{hint}')


def _warn(report: dict[str, Any], text: str) -> None:
    """Print a warning and add it to every method's report entry."""
    print(f'warning: {text}', file=sys.stderr)
    for entry in report.values():
        entry.setdefault('warnings', []).append(text)


WIDE_DEG = 80.0
"""Off-axis angle beyond which half a camera's observations make its focal length suspect."""
NARROW_DEG = 0.01
"""Field of view (half-angle) within which all of a camera's observations make it suspect."""


def _warn_focal_lengths(problem: BAProblem, report: dict[str, Any]) -> None:
    """Warn about cameras whose focal length cannot be that of their observations.

    Half the observations of a camera more than WIDE_DEG off its axis, or all within
    NARROW_DEG of it: a focal length in other units than the pixels (a wrong column, mm), with
    which the solve converges to nonsense without a sign of it.
    """
    obs = problem.obs
    off_axis = np.degrees(np.arccos(np.clip(obs.bearings_c[:, 2], -1.0, 1.0)))
    counts = np.bincount(obs.cam_idx, minlength=problem.n_cams)
    wide = 2 * np.bincount(obs.cam_idx, off_axis > WIDE_DEG, problem.n_cams) >= counts
    narrow = np.bincount(obs.cam_idx, off_axis > NARROW_DEG, problem.n_cams) == 0
    wide_text = f'half of their observations or more over {WIDE_DEG:g} degrees off the axis'
    narrow_text = f'all their observations within {NARROW_DEG:g} degrees of the optical axis'
    for bad, what in ((wide & (counts > 0), wide_text), (narrow & (counts > 0), narrow_text)):
        if (cams := np.flatnonzero(bad)).size:
            i = int(cams[0])
            _warn(report, f'{cams.size} cameras (the first: camera {i}, focal length '
                  f'{problem.intrinsics.fx[i]:g} px) have {what}: is the focal length in pixels?')


def _warn_non_finite(results: list[SolveResult], report: dict[str, Any]) -> None:
    """Mark a solve whose cost is not finite as not converged, with a warning."""
    entries = [report] if len(results) == 1 and 'param' in report else list(report.values())
    for result, entry in zip(results, entries, strict=True):
        if math.isfinite(result.final_cost):
            continue
        text = (f'{result.options.param.value}-{result.options.solver.value}: the final cost '
                'is not finite; the result is not usable')
        print(f'warning: {text}', file=sys.stderr)
        entry['converged'] = False
        entry.setdefault('warnings', []).append(text)
