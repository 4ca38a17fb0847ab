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
"""ament copyright check: ament_copyright is not on PyPI, so this runs under colcon only.

``scripts/copyright_headers --check`` lists the files without the header anywhere.
"""

import pytest


@pytest.mark.copyright
@pytest.mark.linter
def test_copyright():
    """Source files carry a copyright header (as in the ros2 package template)."""
    main = pytest.importorskip('ament_copyright.main').main
    rc = main(argv=['.', 'test'])
    assert rc == 0, 'Found errors'


@pytest.mark.linter
def test_every_source_has_the_license_header():
    """Every Python source carries the Apache-2.0 header (our check where ament's is missing)."""
    from pathlib import Path
    import subprocess
    import sys

    script = Path(__file__).resolve().parents[1] / 'scripts' / 'copyright_headers'
    proc = subprocess.run([sys.executable, str(script), '--check'], capture_output=True,
                          text=True, check=False)
    assert proc.returncode == 0, 'files without the header:\n' + proc.stdout
