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
"""ament pep257 check (runs under colcon test, and in our CI via the PyPI ament linters)."""

import pytest


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    """The package and its tests pass ament_pep257 with Google-style docstrings."""
    main = pytest.importorskip('ament_pep257.main').main
    # Our docstrings follow the Google convention (Args/Returns/Raises sections).
    rc = main(argv=['--convention', 'google', '.', 'test'])
    assert rc == 0, 'Found code style errors / warnings'
