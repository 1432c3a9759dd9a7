"""Why an MPC solve failed, and what the controller applied instead (issue 46).

Each failed solve gets one of :data:`CAUSES` from its status (:class:`~.mpc.MPC`'s ``info``):
the QP solver's or IPOPT's unified return status where the solver gave one (CasADi's
``SOLVER_RET_INFEASIBLE``, ``SOLVER_RET_LIMITED``, ``SOLVER_RET_NAN``), else the SQP's own
("non-finite prediction", "line search failed": no decrease of the cost along the
Gauss-Newton step). :func:`fallback` says, per solver, which command a failed solve applies.
A controller that raised (its build, or a loop) is summed up in one line by :func:`failure`.
"""

from __future__ import annotations

import traceback
from collections import Counter

from softpinn.errors import UserError

__all__ = ["CAUSES", "cause", "count_causes", "failure", "fallback"]

#: the causes of a failed solve
CAUSES = ("infeasible", "iteration limit", "numerical", "other")

_UNIFIED = {"SOLVER_RET_INFEASIBLE": "infeasible", "SOLVER_RET_LIMITED": "iteration limit",
            "SOLVER_RET_NAN": "numerical"}
_IPOPT = {"Infeasible_Problem_Detected": "infeasible",
          "Maximum_Iterations_Exceeded": "iteration limit",
          "Maximum_CpuTime_Exceeded": "iteration limit",
          "Maximum_WallTime_Exceeded": "iteration limit",
          "Restoration_Failed": "numerical", "Error_In_Step_Computation": "numerical",
          "Invalid_Number_Detected": "numerical", "Search_Direction_Becomes_Too_Small":
          "numerical", "Diverging_Iterates": "numerical", "Not_Enough_Degrees_Of_Freedom":
          "infeasible"}


def cause(status, unified=None) -> str:
    """The cause of a failed solve with ``status`` (and the solver's unified return status)."""
    if unified in _UNIFIED:
        return _UNIFIED[unified]
    text = str(status)
    if text in _IPOPT:
        return _IPOPT[text]
    if text.startswith(("non-finite", "line search")):
        return "numerical"
    if text.startswith("QP failed"):  # a QP solver's unknown status (daqp on an indefinite H)
        return "numerical"
    return "other"


def count_causes(success, causes) -> dict[str, int]:
    """{cause: failed solves} over the steps (``causes``: one per step, None where it
    succeeded), in the order of :data:`CAUSES`."""
    got = Counter(c or "other" for ok, c in zip(success, causes, strict=False) if not ok)
    return {c: got[c] for c in CAUSES if got[c]}


def fallback(solver: str) -> str:
    """The command a failed solve of ``solver`` applies."""
    if solver == "sqp":
        return ("a failed SQP solve applies the first input of its last accepted plan: the "
                "previous plan shifted by one step (the last input held where there is none), "
                "clipped to the input bounds, when no step of this solve was accepted; the "
                "last input where that is not finite. The next solve starts from the last "
                "input held")
    return ("a failed IPOPT solve applies the first input of its last iterate, or the last "
            "input where that is not finite; the next solve starts cold (no warm start)")


def failure(exc: BaseException, stage: str) -> dict:
    """A controller that raised ``exc`` while at ``stage`` ("build" or a reference's name):
    its error in one line, the exception's type, and the traceback where it is no UserError."""
    line = " ".join(str(exc).split()) or type(exc).__name__
    if len(line) > 300:
        line = line[:297] + "..."
    out = {"stage": stage, "error": line, "type": type(exc).__name__}
    if not isinstance(exc, UserError):
        out["traceback"] = "".join(traceback.format_exception(exc))
    return out
