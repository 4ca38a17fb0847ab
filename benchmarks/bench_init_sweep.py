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
"""Sweep of the global initialization over the shared problems and harder variants of them.

For every problem and variant (pmba_ros.sim.variants: shuffled, camera subsets, every 2nd /
3rd camera, mixed focal lengths, outlier tracks) it runs ``global_init`` (one BA) and PMBA
from the problem's own start on the same sub-problem, and prints one row each: features used,
rotation residuals, NLS convergence, BA iterations and termination, final RMS vs the reference.

Usage::

    python benchmarks/bench_init_sweep.py                       # every case, every variant
    python benchmarks/bench_init_sweep.py --case trafalgar --variant stride2 --json out.json

Columns: ``cams`` used / reachable (largest component of the graph of camera pairs sharing
``min_pair_matches`` tracks) / input; ``feat%`` features used and ``reach%`` features seen
twice by reachable cameras (outlier tracks excluded from both); ``recov`` features anchored
after the positions; ``out`` added outlier tracks left in. A row passes when the BA converged
(not an iteration cap), its RMS is within 1 % of the reference and at least 95 % of the
reachable features were used. The exit status is 1 if a row fails.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import json
import logging
import os
from pathlib import Path
import sys
from typing import Any, TYPE_CHECKING

from pmba_ros._heap import keep_freed_memory

if TYPE_CHECKING:
    from pmba_ros.core.problem import BAProblem

DATA = Path(__file__).resolve().parents[1].parent / 'shared' / 'data'


def _bal(name: str) -> Callable[[], BAProblem | None]:
    def load() -> BAProblem | None:
        from pmba_ros.io.bal import read_bal
        path = DATA / 'bal' / name
        if not path.exists():
            return None
        return read_bal(path)
    return load


def _fake_pile() -> BAProblem | None:
    from pmba_ros.io.parallaxba_files import read_parallaxba, triangulate_points
    path = DATA / 'parallaxba' / 'fake-pile'
    if not path.exists():
        return None
    problem = read_parallaxba(path)
    return problem.with_points(triangulate_points(problem))


def _street() -> BAProblem | None:
    from pmba_ros.sim.scenes import street_scene
    # The reference starts from the ground truth (a simulation's "file" start is perturbed).
    return street_scene(0, n_cams=40, n_points=3000, max_track_length=12).gt


CASES: dict[str, Callable[[], BAProblem | None]] = {
    'ladybug1800': _bal('bal-ladybug-problem-49-7776-pre-shrink-1800.txt'),
    'ladybug': _bal('problem-49-7776-pre.txt'),
    'trafalgar': _bal('problem-21-11315-pre.txt'),
    'dubrovnik3': _bal('dubrovnik-3-7-pre.txt'),
    'fake_pile': _fake_pile,
    'street40': _street,
}

_COLUMNS = (('case', '<12', 's'), ('variant', '<10', 's'), ('cams', '>9', 's'),
            ('feat%', '>6', '.1f'), ('reach%', '>6', '.1f'), ('recov', '>6', 'd'),
            ('out', '>5', 'd'),
            ('rot_med', '>8', '.3f'), ('rot_max', '>8', '.3f'), ('nls_it', '>6', 'd'),
            ('nls_ok', '>6', 's'),
            ('nls_px', '>8', '.2f'), ('rms0', '>9', '.2f'), ('ba_it', '>5', 'd'),
            ('termination', '<18', 's'), ('rms', '>8', '.4f'), ('ref_rms', '>8', '.4f'),
            ('ratio', '>7', '.4f'), ('time_s', '>7', '.1f'), ('pass', '>5', 's'))


def _format(values: dict[str, Any]) -> str:
    cells = []
    for name, align, spec in _COLUMNS:
        v = values.get(name, '')
        text = format(v, spec) if v != '' and not isinstance(v, str) else str(v)
        cells.append(format(text, align))
    return ' '.join(cells)


def run(cases: list[str], variants: list[str] | None, seed: int) -> list[dict[str, Any]]:
    """Run the sweep and print one row per (case, variant); return the rows."""
    from pmba_ros.errors import PmbaError
    from pmba_ros.init.assess import assess
    from pmba_ros.sim.variants import make_variants

    rows: list[dict[str, Any]] = []
    print(_format({name: name for name, _, _ in _COLUMNS}))
    for case in cases:
        loaded = CASES[case]()
        if loaded is None:
            print(f'{case}: data not available, skipped')
            continue
        for variant in make_variants(loaded, variants, seed):
            base: dict[str, Any] = {'case': case, 'variant': variant.name}
            try:
                pts = variant.problem.points_w
                assert pts is not None
                row, _ = assess(variant.problem, pts, outlier_ids=variant.outlier_ids)
            except PmbaError as err:
                out = {**base, 'error': f'{type(err).__name__}: {err}', 'passed': False}
                print(_format({**base, 'termination': type(err).__name__, 'pass': 'no'}))
                rows.append(out)
                continue
            values = row.to_dict()
            out = {**base, **values, 'passed': row.passed()}
            rows.append(out)
            print(_format({
                **base, 'cams': f'{row.cams_used}/{row.reachable_cams}/{row.n_cams}',
                'feat%': row.features_used_pct, 'reach%': row.reachable_feats_pct,
                'recov': row.features_recovered,
                'out': row.outliers_kept,
                'rot_med': row.rot_median_deg, 'rot_max': row.rot_max_deg,
                'nls_it': row.nls_iterations, 'nls_ok': 'yes' if row.nls_converged else 'NO',
                'nls_px': row.nls_px, 'rms0': row.ba_rms0_px, 'ba_it': row.ba_iterations,
                'termination': row.ba_termination, 'rms': row.rms_px,
                'ref_rms': row.ref_rms_px, 'ratio': row.rms_ratio, 'time_s': row.init_s,
                'pass': 'yes' if row.passed() else 'NO'}))
            sys.stdout.flush()
    return rows


def main(argv: list[str] | None = None) -> int:
    """Parse arguments, run the sweep, optionally write JSON; exit 1 if a row failed."""
    keep_freed_memory()
    from pmba_ros.sim.variants import VARIANTS
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--case', choices=sorted(CASES), action='append')
    parser.add_argument('--variant', choices=sorted(VARIANTS), action='append')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--json', type=Path)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    print(f'cpu_count={os.cpu_count()}, load={os.getloadavg()[0]:.2f}')
    rows = run(args.case or list(CASES), args.variant, args.seed)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + '\n')
    return 0 if all(r['passed'] for r in rows) else 1


if __name__ == '__main__':
    raise SystemExit(main())
