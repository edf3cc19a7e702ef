"""The root error of the calib package, and the failure value for degenerate estimates."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


class CalibrationError(ValueError):
    """Bad input or an impossible calibration. The message names the camera, frame or field,
    and says what to do next."""


@dataclass(frozen=True)
class Failure:
    """A degenerate estimate: falsy, and says why (scikit-image style)."""

    reason: str

    def __bool__(self) -> Literal[False]:  # Literal: `if result:` narrows ``X | Failure`` to X for mypy
        return False

    def __str__(self) -> str:
        return self.reason
