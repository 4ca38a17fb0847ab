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
"""Exception types of pmba_ros; every error the package raises derives from PmbaError.

:class:`Cancelled` is no error: a computation stopped on request.
"""

from __future__ import annotations


class PmbaError(Exception):
    """Root of all pmba_ros errors."""


class ProblemError(PmbaError, ValueError):
    """A bundle-adjustment problem or its input data is malformed."""


class FormatError(PmbaError, ValueError):
    """A data file does not follow its format (names file, line and problem)."""


class DegenerateGeometryError(PmbaError):
    """The geometry cannot be parameterized (zero baseline, pure rotation, ...)."""


class SolverError(PmbaError):
    """The solver cannot proceed (no free parameters, non-finite start, ...)."""


class ReducedSystemError(SolverError):
    """The reduced camera system is not positive definite."""


class InitError(PmbaError):
    """Global initialization cannot produce a problem from the given tracks."""


class MessageError(PmbaError, ValueError):
    """A ROS message does not fit the layout it was declared to have."""


class BagError(PmbaError):
    """A recording cannot be read or written."""


class EvaluationError(PmbaError, ValueError):
    """Trajectories cannot be compared (no overlap, too few poses, bad format)."""


class Cancelled(BaseException):
    """A computation stopped on request: the node's solver thread at shutdown or ``~/reset``.

    Raised between solver iterations and initialization stages; the estimate it interrupts is
    left half-updated, so it is only raised where that state is dropped next. A BaseException,
    as :class:`asyncio.CancelledError` is: the back-end's ``except Exception`` guards, which
    count a failed update and go on, must let it through.
    """
