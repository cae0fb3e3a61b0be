"""Configuration models (pydantic) for the robot, the task and the planning core.

Every parameter the paper names lives here with the paper's value as default:
operating height 0.8 m, ε_min = 0.05, ε_max = 0.10 (squared metres, as printed in EPMC),
γ = 2, Σ_w = r_w·I. Values the paper leaves open (δ, ξ, β, camera, nozzle) have defaults
chosen for the Spot + Z1 set-up and are documented in docs/model.md.

Models are frozen so a config can be hashed (reachability cache key) and shared safely.
"""

from __future__ import annotations

import hashlib
import json
import re
import typing
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator


def _takes_bool(annotation: Any) -> bool:
    """Whether a field annotation admits a bool (bool itself, Any, or a union/container with one)."""
    if annotation is bool or annotation is Any:
        return True
    return any(_takes_bool(a) for a in typing.get_args(annotation))


def _has_bool(v: Any) -> bool:
    return isinstance(v, bool) or (isinstance(v, (list, tuple)) and any(_has_bool(x) for x in v))


def not_bool(v: Any) -> Any:
    """Before-validator of a number: YAML 1.1 reads yes/no/on/off as booleans, which pydantic
    would take as 1 / 0 (`StrictNumbers` applies it to every numeric field of a model)."""
    if _has_bool(v):
        raise ValueError("a number is needed, not a yes/no value")
    return v


class StrictNumbers(BaseModel):
    """Refuses yes/no values where a number is expected: YAML 1.1 reads yes/no/on/off as booleans
    and pydantic would take them as 1 / 0 (a `seed: yes` or `max_speed: on` would pass)."""

    @field_validator("*", mode="before")
    @classmethod
    def _no_yes_no(cls, v: Any, info: ValidationInfo) -> Any:
        f = cls.model_fields.get(info.field_name or "")
        return v if f is None or _takes_bool(f.annotation) else not_bool(v)


class _Frozen(StrictNumbers):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


# Plausibility bounds: a value beyond them is a typo or a unit error (mm for m, deg for rad), and
# would otherwise surface mid-run as a numeric failure (a singular matrix, an empty map).
MAX_OFFSET = 2.0  # m: a mount, hand-eye or tool offset on a Spot + Z1
_Offset = typing.Annotated[float, Field(ge=-MAX_OFFSET, le=MAX_OFFSET)]
MAX_ANGLE = 6.2832  # rad (2π): a roll, pitch or yaw of 90 or 180 is degrees
_Angle = typing.Annotated[float, Field(ge=-MAX_ANGLE, le=MAX_ANGLE)]


class Transform(_Frozen):
    """A rigid transform given as translation (m) and roll-pitch-yaw (rad, fixed-axis XYZ)."""

    xyz: tuple[_Offset, _Offset, _Offset] = (0.0, 0.0, 0.0)
    rpy: tuple[_Angle, _Angle, _Angle] = (0.0, 0.0, 0.0)


class BodyConfig(_Frozen):
    """Spot body: an SE(2) pose at a fixed operating height (assumption a.1: holonomic)."""

    operating_height: float = Field(0.8, gt=0.0, le=2.0, description="height of the arm base above ground (m); paper: 0.8")
    arm_mount: Transform = Field(
        default_factory=Transform,
        description="arm base (Z1 link00) in the body frame; the body frame origin is at operating height; level (yaw only)",
    )

    @field_validator("arm_mount")
    @classmethod
    def _level_mount(cls, v: Transform) -> Transform:
        # the reachability maps turn joint 1 about the vertical and put the ground at z = −height in
        # the arm-base frame: a tilted base would get a level base's maps (an audit measured 15 of 120
        # targets answered wrongly at 0.25 rad pitch), so it is refused rather than mis-planned
        if v.rpy[0] != 0.0 or v.rpy[1] != 0.0:
            raise ValueError(f"roll and pitch must be 0 (got {v.rpy[0]:.4g}, {v.rpy[1]:.4g} rad): "
                             "a tilted arm base is not modelled; only the yaw may turn it")
        return v
    # The body is modelled, as seen from the arm, as a vertical cylinder around the arm base:
    # the arm may not enter it and the camera / flame may not look through it. This is what
    # gives R_o and R_m their inner bounds (the robot cannot see or flame under itself).
    keepout_radius: float = Field(0.35, ge=0.0, le=MAX_OFFSET, description="radius of the body keep-out cylinder (m)")
    keepout_depth: float | None = Field(
        None, ge=0.0, le=MAX_OFFSET, description="cylinder extends this far below the arm base (m); None: down to the ground (legs)"
    )
    position_tolerance: float = Field(
        0.015, ge=0.0, le=0.5, description="expected body placement error (m); planned stops keep this far inside R_o and R_m"
    )
    max_speed: float = Field(0.8, gt=0.0, le=5.0, description="body translation speed limit (m/s)")
    max_yaw_rate: float = Field(1.0, gt=0.0, le=10.0, description="body yaw rate limit (rad/s)")
    max_accel: float = Field(0.8, gt=0.0, le=20.0, description="body acceleration limit (m/s^2)")


ARM_JOINTS = 6  # the Z1 (RobotModel refuses a URDF with another count)


class ArmConfig(_Frozen):
    """Unitree Z1 loaded from its URDF (example-robot-data) with pinocchio."""

    urdf: str | None = Field(None, description="path to z1.urdf; default: the copy shipped in example-robot-data")
    flange_frame: str = Field("link06", description="URDF link carrying camera and nozzle")
    locked_joints: tuple[str, ...] = Field(("jointGripper",), description="joints held at 0 (gripper)")
    stow_joints: tuple[float, ...] = Field((0.0, 0.0, -0.005, 0.0, 0.0, 0.0), description="stowed configuration (rad)")
    max_joint_speed: float = Field(1.5, gt=0.0, le=10.0, description="joint speed limit used by the bench (rad/s)")
    min_clearance: float = Field(0.03, ge=0.0, le=1.0, description="arm points must stay this far above ground (m)")

    @field_validator("stow_joints")
    @classmethod
    def _six(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if len(v) != ARM_JOINTS:
            raise ValueError(f"the Z1 has {ARM_JOINTS} joints: give {ARM_JOINTS} values (got {len(v)})")
        return v


MAX_PIXELS = 8192  # px per image side (8K; the bench renders every frame at this size)
MAX_DISTORTION = 1e4  # |coefficient|: calibrations of fisheye-like lenses reach tens (rational k4..k6)


class CameraConfig(_Frozen):
    """Pinhole camera on the end effector. Resolution u_max × v_max is fixed (assumption a.5)."""

    width: int = Field(1280, gt=0, le=MAX_PIXELS, description="u_max (px)")
    height: int = Field(720, gt=0, le=MAX_PIXELS, description="v_max (px)")
    # under 1 px is a unit error (metres: a 4 mm lens is 0.004), and 1e-20 px made the maps NaN
    fx: float = Field(1000.0, ge=1.0, le=1e5, description="focal length (px)")
    fy: float = Field(1000.0, ge=1.0, le=1e5, description="focal length (px)")
    cx: float | None = Field(None, ge=-1e5, le=1e5, description="principal point (px); default: image centre")
    cy: float | None = Field(None, ge=-1e5, le=1e5, description="principal point (px); default: image centre")
    distortion: tuple[float, ...] = Field(
        (),
        description="lens distortion as cv2.calibrateCamera gives it: (k1, k2, p1, p2), (k1, k2, p1, p2, k3) "
        "(ROS plumb_bob) or 8 values (rational_polynomial); () or zeros: none",
    )
    # Hand-eye transform: camera optical frame (z forward, x right, y down) in the flange frame.
    # Default: 6 cm above the tool axis, looking along the flange x axis.
    hand_eye: Transform = Field(
        default_factory=lambda: Transform(xyz=(0.06, 0.0, 0.06), rpy=(-1.5707963267948966, 0.0, -1.5707963267948966))
    )

    @field_validator("distortion")
    @classmethod
    def _distortion_form(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        from .lens import LENGTHS

        if len(v) not in LENGTHS:
            raise ValueError(f"give 4, 5 or 8 distortion coefficients in OpenCV's order (k1, k2, p1, p2, k3, ...), or none (got {len(v)})")
        if any(abs(c) > MAX_DISTORTION for c in v):
            raise ValueError(f"a distortion coefficient beyond ±{MAX_DISTORTION:g} is no lens calibration")
        return v

    @model_validator(mode="after")
    def _distortion_inverts(self) -> "CameraConfig":
        from .lens import check

        cx, cy = self.principal_point
        why = check([[self.fx, 0.0, cx], [0.0, self.fy, cy], [0.0, 0.0, 1.0]], self.distortion, self.width, self.height)
        if why is not None:
            raise ValueError(f"distortion {list(self.distortion)} {why}: is it this camera's calibration, for this resolution?")
        return self

    @property
    def principal_point(self) -> tuple[float, float]:
        cx = self.cx if self.cx is not None else (self.width - 1) / 2.0
        cy = self.cy if self.cy is not None else (self.height - 1) / 2.0
        return cx, cy


class NozzleConfig(_Frozen):
    """Flame nozzle tool frame: its x axis is the flame direction; X_e of EPMC is its origin.

    Default: the nozzle tip of a 0.45 m flame lance along the flange axis. With the arm base at
    0.8 m the Z1 (joint 2 ∈ [0°, 170°]: the upper arm never points below the shoulder) cannot bring a
    short tool within √ε_max = 0.32 m of the ground; a lance, as on hand-held flame weeders, can.
    """

    tool: Transform = Field(default_factory=lambda: Transform(xyz=(0.45, 0.0, 0.0)))
    max_tilt: float = Field(1.2, gt=0.0, le=1.5707963267948966, description="max angle of the flame axis from vertical (rad)")


class RobotConfig(_Frozen):
    body: BodyConfig = Field(default_factory=BodyConfig)
    arm: ArmConfig = Field(default_factory=ArmConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    nozzle: NozzleConfig = Field(default_factory=NozzleConfig)

    def digest(self) -> str:
        """Stable hash of every field: the reachability cache key."""
        blob = json.dumps(self.model_dump(mode="json"), sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


MAX_EPS = 4.0  # m²: EPMC distances beyond 2 m are beyond the arm and the lance


class TaskConfig(_Frozen):
    """Task constraints and energy model (paper §IV-A, §IV-D, §IV-E)."""

    delta: float = Field(0.15, gt=0.0, le=1.0, description="δ: min projected-TROI area / image area (NSV resolution)")
    eps_min: float = Field(0.05, ge=0.0, le=MAX_EPS, description="ε_min: min ‖X_e − X̄_w‖² (m²) for EPMC")
    eps_max: float = Field(0.10, gt=0.0, le=MAX_EPS, description="ε_max: max ‖X_e − X̄_w‖² (m²) for EPMC")
    xi: float = Field(3.0, gt=0.0, le=60.0, description="ξ: flame hold time for MTC (s); a minute is beyond any weed")
    gamma: float = Field(2.0, ge=0.0, le=1e3, description="γ: energy per unit distance d")
    beta: float = Field(0.0, ge=0.0, le=1e3, description="β: weight of the orientation term in d (paper: not given)")
    distance_form: Literal["squared", "euclidean"] = Field(
        "euclidean", description="‖ΔX‖² as printed, or plain ‖ΔX‖ (Table I comes out of the plain form)"
    )
    sigma_reading: Literal["variance", "std"] = Field(
        "variance", description="Σ_w = scale·r_w·I read as a covariance (σ = √(scale·r_w)) or as σ = scale·r_w"
    )
    sigma_scale: float = Field(1.0, ge=0.01, le=10.0, description="scale on r_w in Σ_w (≥ 0.01: a σ of nothing overflows p(x_b,k1)'s χ² tail)")

    @model_validator(mode="after")
    def _eps_order(self) -> "TaskConfig":
        if self.eps_min > self.eps_max:
            raise ValueError(f"eps_min ({self.eps_min}) must not exceed eps_max ({self.eps_max})")
        return self

    def sigma(self, r_w: float) -> float:
        """Standard deviation σ of the isotropic MPOI prior N(X_w, σ²I) for a TROI of radius r_w."""
        s = self.sigma_scale * r_w
        return float(s**0.5) if self.sigma_reading == "variance" else float(s)


MIN_TROI_RADIUS = 0.001  # m: r_w below a millimetre is no weed's region (at 1e-20 p(x_b,k1) was NaN everywhere)


class ReachabilityConfig(_Frozen):
    """Resolution of the inverse-reachability maps (see docs/model.md for the measured error)."""

    joint_steps: tuple[int, int, int, int] = Field(
        (48, 48, 25, 13), description="FK samples of joints 2..5 (joint 1 by symmetry, joint 6 rolls the tool)"
    )
    roll_steps: int = Field(4, ge=1, description="camera roll samples (joint 6)")
    radial_step: float = Field(0.01, gt=0.0, description="radial bin of the maps (m)")
    radial_max: float = Field(2.0, gt=0.0, description="largest target distance from the arm axis considered (m)")
    troi_radius_step: float = Field(0.01, gt=0.0, description="TROI radius bin of R_o (m)")
    troi_radius_max: float = Field(0.5, gt=0.0, description="largest TROI radius R_o is built for (m)")
    cache_dir: str | None = Field(None, description="map cache; default $XDG_CACHE_HOME/capm-field or ~/.cache/capm-field")


TASK_FLAGS = {"delta": "--delta", "eps_min": "--eps-min", "eps_max": "--eps-max", "gamma": "--gamma",
              "distance_form": "--distance", "sigma_reading": "--sigma"}  # TaskConfig fields the bench CLIs set


def build(model: type[BaseModel], where: str = "", flags: dict[str, str] | None = None, **values):
    """Instantiate a config model; a validation error becomes one UserError line naming the field,
    or the command-line option that gave it (`flags`: field name → option, e.g. "delta" → "--delta")."""
    from pydantic import ValidationError

    from .errors import UserError

    try:
        return model(**values)
    except ValidationError as e:
        err = e.errors()[0]
        loc = ".".join(str(x) for x in err.get("loc", ())) or where
        prefix = f"{where}.{loc}" if where and loc != where else loc
        got = f" (got {err['input']!r})" if "input" in err and not isinstance(err["input"], dict) else ""
        msg = err["msg"]
        if flags:
            if loc in flags:
                prefix = flags[loc]
            elif loc == where:  # a check across fields: its message names them
                msg = re.sub(r"\b(" + "|".join(map(re.escape, flags)) + r")\b", lambda m: flags[m.group(1)],
                             msg.removeprefix("Value error, "))
                raise UserError(f"{msg}{got}") from e
        raise UserError(f"{prefix or model.__name__}: {msg}{got}") from e
