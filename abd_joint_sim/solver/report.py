"""What a step did: `Status` of Newton and the immutable `StepReport` (a NamedTuple)."""
from __future__ import annotations

import enum
from typing import NamedTuple


class Status(str, enum.Enum):
    """Newton's outcome (a str, so `report.status == 'converged'` reads as before)."""

    CONVERGED = 'converged'
    MAX_ITERATIONS = 'max_iterations'
    LINE_SEARCH_FAILED = 'line_search_failed'
    NONFINITE = 'nonfinite'

    def __str__(self) -> str:
        return self.value


#: newton.py's status codes in order
STATUS_BY_CODE = (Status.CONVERGED, Status.MAX_ITERATIONS, Status.LINE_SEARCH_FAILED, Status.NONFINITE)


class StepReport(NamedTuple):
    """What one call of `World.step` did (the last step when several were taken). A
    NamedTuple: a frozen dataclass cost a tenth of a one-body step's time to build."""

    time: float = 0.0                   #: [s] simulation time after the step
    status: Status = Status.CONVERGED   #: worst Newton status over the sub-steps
    converged: bool = True
    newton_iterations: int = 0          #: summed over sub-steps
    line_search_iterations: int = 0     #: line-search halvings, summed over sub-steps
    substeps: int = 1
    max_joint_separation: float = 0.0   #: [m] after the step
    max_step_rotation: float = 0.0      #: [rad] largest joint rotation of a (sub-)step
    warnings: tuple = ()                #: one line each, naming time, joint/body and value
