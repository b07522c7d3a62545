"""Settings of a replay simulation: the PyBullet fidelity and the measurement noise of the
recorded channels, shared by every robot's replay and recorder."""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from realitygap.robots.world import World

__all__ = ["MeasurementNoise", "SimSettings", "default_solver_iterations"]


def default_solver_iterations() -> int:
    """The solver iterations a :class:`~realitygap.robots.world.World` uses by default."""
    param = inspect.signature(World.__init__).parameters.get("solver_iterations")
    if param is None or not isinstance(param.default, int):  # pragma: no cover - defensive
        return 10
    return int(param.default)


@dataclass(frozen=True)
class SimSettings:
    """Fidelity of the PyBullet simulation used for replays.

    Parameters
    ----------
    physics_hz : float
        Target physics rate, Hz; the step is adjusted so that a whole number
        of physics steps fits one control period of the log.
    solver_iterations : int
        Constraint-solver iterations per physics step; 0 means the
        :class:`~realitygap.robots.world.World` default (the env's).
    """

    physics_hz: float = 240.0
    solver_iterations: int = 0

    def __post_init__(self) -> None:
        if not (self.physics_hz > 0 and math.isfinite(self.physics_hz)):
            raise ValueError(f"physics_hz must be a positive number, got {self.physics_hz!r}")
        if self.solver_iterations == 0:
            object.__setattr__(self, "solver_iterations", default_solver_iterations())
        if int(self.solver_iterations) != self.solver_iterations or self.solver_iterations < 1:
            raise ValueError(
                f"solver_iterations must be a positive integer, got {self.solver_iterations!r}"
            )

    @classmethod
    def for_log(cls, log: Any, default: SimSettings | None = None) -> SimSettings:
        """The settings recorded in ``log.meta["sim"]`` (a simulated log: any object with a
        ``meta`` mapping, e.g. a :class:`~realitygap.diagnosis.logs.log.Log`), else ``default``."""
        sim = log.meta.get("sim")
        base = default if default is not None else cls()
        if not isinstance(sim, Mapping):
            return base
        return cls(
            physics_hz=float(sim.get("physics_hz", base.physics_hz)),
            solver_iterations=int(sim.get("solver_iterations", base.solver_iterations)),
        )

    def to_meta(self) -> dict[str, Any]:
        return {"physics_hz": self.physics_hz, "solver_iterations": self.solver_iterations}


@dataclass(frozen=True)
class MeasurementNoise:
    """Gaussian noise added to recorded channels (standard deviations; SI units).

    ``truth_xy`` / ``truth_theta`` for the motion-capture ground truth,
    ``camera_xy`` / ``camera_theta`` for the camera localisation.
    """

    truth_xy: float = 0.0
    truth_theta: float = 0.0
    camera_xy: float = 0.0
    camera_theta: float = 0.0
