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
"""Global initialization of PMBA from feature tracks alone (pmba.md §3-4)."""

import contextlib
import importlib


def import_initialization() -> None:
    """Import the initialization (and OpenCV, an extra) before input rather than at first use."""
    with contextlib.suppress(ImportError):   # no OpenCV: the first initialization says so
        importlib.import_module('pmba_ros.init.pipeline')
