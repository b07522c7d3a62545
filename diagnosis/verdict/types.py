"""The verdict's types."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = ["Verdict"]


# --------------------------------------------------------------------------- residual structure
@dataclass
class Verdict:
    """The conclusion of an attribution.

    ``kind`` is ``"effects"`` (``effects`` names them), ``"unexplained"`` or
    ``"none"`` (no significant gap on the held-out data, nor on the training data).
    """

    kind: str
    effects: tuple[str, ...]
    reason: str
    margin: float
    confidence: str
    residual: dict[str, Any]
    ambiguous_with: list[str] = field(default_factory=list)
    notes: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str | list[str]:
        """What the JSON ``verdict`` holds: a list of effect names or a keyword."""
        if self.kind == "effects":
            return list(self.effects)
        return self.kind
