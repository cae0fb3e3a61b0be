"""Key states as data (paper §III-B): a plan is a list the executive walks through; the log records each.

Sequence for one TROI: [x_k0, x_b,k1, x_e,k2, (x_b,k3), x_e,k3, x_kmax]
  x_k0     start body pose                      x_e,k2  arm: observe the TROI (NSV)
  x_b,k1   body: observation stop               x_b,k3  body: reposition (lower branch only)
  x_e,k3   arm: flame the MPOI (EPMC, hold ξ)   x_kmax  body: end pose (towards the next TROI)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from .geometry import SE2

Label = Literal["x_k0", "x_b,k1", "x_e,k2", "x_b,k3", "x_e,k3", "x_kmax"]


@dataclass(frozen=True)
class TROI:
    """Target region of interest R_w^TROI: ground disc centre X_w = (x, y) and radius r_w."""

    x: float
    y: float
    r: float
    id: str = ""

    @property
    def xy(self) -> tuple[float, float]:
        return (self.x, self.y)


@dataclass(frozen=True)
class KeyState:
    """One key state. Body states carry the body pose; arm states also name what the arm serves."""

    label: Label
    body: SE2
    arm: Literal["observe", "flame"] | None = None
    target: tuple[float, float] | None = None  # X_w for observe, X̄_w (or X_w if unknown) for flame
    radius: float | None = None  # r_w for observe

    def to_dict(self) -> dict:
        return {
            "label": self.label,
            "body": list(self.body.as_tuple()),
            "arm": self.arm,
            "target": list(self.target) if self.target else None,
            "radius": self.radius,
        }


@dataclass(frozen=True)
class Plan:
    """A planner's answer before observation.

    `key_states` is the branch the planner commits to now (upper branch for CAPM, with its
    lower-branch fallback `fallback_k3` planned against X_w). `p_upper` = p(x_b,k1);
    `expected_cost` = c_0 + p·c_u + (1 − p)·c_l (paper eq. 11) under the planner's own model.
    """

    planner: str
    troi: TROI
    start: SE2
    end: SE2
    key_states: tuple[KeyState, ...]
    p_upper: float
    expected_cost: float
    fallback_k3: SE2 | None = None
    terms: dict = field(default_factory=dict)

    def state(self, label: Label) -> KeyState | None:
        return next((k for k in self.key_states if k.label == label), None)

    @property
    def x_b_k1(self) -> SE2:
        k = self.state("x_b,k1")
        assert k is not None
        return k.body


@dataclass(frozen=True)
class Outcome:
    """What happened after observation: the executed key states, the branch and the energy."""

    planner: str
    branch: Literal["upper", "lower", "blind"]
    key_states: tuple[KeyState, ...]
    cost: float
    body_moves: int
    success: bool
