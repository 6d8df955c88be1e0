"""A refused plan: the PlanResult that answers a request the planner did not (or could not) plan."""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

from ff_planner.model.profile import PlanRequest, PlanResult


def as_vector(x: Any) -> np.ndarray:
    """``x`` as a flat float array (rad); an empty one when it cannot be read."""
    try:
        return np.asarray(list(x), dtype=float).ravel()
    except (TypeError, ValueError):
        return np.zeros(0)


def failure(request: Optional[PlanRequest], code: str, message: str, **kw: Any) -> PlanResult:
    """A PlanResult refusing ``request`` with PlanTrajectory error ``code`` and ``message``.

    ``request`` may be None (nothing of it could be read) or partly filled in; whatever can be
    read of it is echoed. ``kw`` sets further PlanResult fields.
    """
    r = request
    return PlanResult(success=False, message=message, profile=None,
                      model=getattr(r, "model", "") or "", params=None,
                      q0=as_vector(getattr(r, "q0", ())), qf=as_vector(getattr(r, "qf", ())),
                      uncertain=list(getattr(r, "uncertain", ()) or ()),
                      objective=getattr(r, "objective", "") or "", error_code=code, **kw)
