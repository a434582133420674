"""``central``: keep the robot where the sensor names a cell (the "nothing"-minimising heuristic)."""

from __future__ import annotations

import numpy as np

from gym_gridloc_agents.planners.base import PlannerPolicy


def nothing_reading(model, nothing: int | None = None) -> int:
    """The sensor's "nothing" reading: ``nothing`` if given, else ``model.sensor.nothing``.
    Raises ``ValueError`` for sensors without one (colour and wall sensors)."""
    if nothing is None:
        nothing = getattr(model.sensor, "nothing", None)
    if nothing is None:
        raise ValueError(
            f"policy 'central' needs a sensor with a 'nothing' reading (RingSensor); {type(model.sensor).__name__} "
            "has none (pass nothing=<reading> to name one)"
        )
    nothing = int(nothing)
    if not 0 <= nothing < model.sensor.n_readings:
        raise ValueError(f"nothing reading {nothing} outside 0..{model.sensor.n_readings - 1}")
    return nothing


class CentralPolicy(PlannerPolicy):
    """``argmin_a P(z' = nothing | b, a) = sum_s (T_a^T b)(s) P(nothing | s)``: keep the robot
    where the sensor names a cell.  ``depth=2``: the expected number of "nothing" readings over two
    steps, the second action chosen after the first reading.  Sensors without a "nothing" reading
    are refused (pass ``nothing=<reading>`` to name one)."""

    name = "central"

    def __init__(self, model, *, nothing: int | None = None, depth: int = 1, **kw) -> None:
        if depth not in (1, 2):
            raise ValueError(f"central depth must be 1 or 2, got {depth!r}")
        self.nothing_arg, self.depth = nothing, int(depth)
        nothing_reading(model, nothing)  # refuse sensors without a "nothing" reading now, not at the first act
        super().__init__(model, **kw)

    @property
    def lik_nothing(self) -> np.ndarray:
        return self.ops.lik[nothing_reading(self.model, self.nothing_arg)].reshape(-1)

    def values(self, b: np.ndarray) -> np.ndarray:
        preds = self.ops.predict_all(b[None])
        lik_nothing = self.lik_nothing
        pn = preds.reshape(self.n_actions, -1) @ lik_nothing
        if self.depth == 2:  # + E_z1[ min_a2 P(nothing at step 2 | b_a1z1, a2) ], closed loop
            A, Z = self.n_actions, self.ops.Z
            joint = self.ops.mdp.joint(preds[:, None], np.arange(Z)[None]).reshape(A * Z, *self.ops.shape)  # mass p(z1 | a1)
            pn2 = (self.ops.predict_all(joint).reshape(A * Z * A, -1) @ lik_nothing).reshape(A, Z, A)
            pn = pn + pn2.min(axis=2).sum(axis=1)
        return pn
