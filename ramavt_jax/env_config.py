"""Static and traced settings of the tracking env: the action set, ``EnvConfig`` (static: shapes and code paths),
``EnvParams`` (traced: every physical value and the target catalogue) and the host-side ``validate_params``.
Re-exported by :mod:`ramavt_jax.env`, whose names (``env.EnvConfig`` ...) are the public ones."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ramavt_jax import dynamics
from ramavt_jax import targets as targets_lib
from ramavt_jax.render import OBSERVATION_MODES, CameraConfig

# 11 velocity commands in the camera frame (original SNCOAT action set), times env.command_speed (EnvParams.speed).
# Module constants are numpy, not jnp: importing the package must not start a JAX backend (a multi-host run calls
# jax.distributed.initialize after the imports).
ACTIONS = np.array(
    [
        [0, 0, 0],
        [1, 0, 0],
        [-1, 0, 0],
        [0, 1, 0],
        [0, -1, 0],
        [0, 0, 1],
        [0, 0, -1],
        [1, 1, 0],
        [1, -1, 0],
        [-1, 1, 0],
        [-1, -1, 0],
    ],
    dtype=np.float32,
)
NUM_ACTIONS = ACTIONS.shape[0]
RETREAT = 6  # back along the camera axis: shrinks a target's bearing in any direction (a search from a blank image)
OBS_CHANNELS = OBSERVATION_MODES  # one home: the renderer defines the modes and their channels

# Hill coordinates of the camera axes (columns): hill = HILL_FROM_CAM @ cam.
HILL_FROM_CAM = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]], dtype=np.float32)


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Static settings (shapes and code paths); changing one recompiles. Validated at construction."""

    camera: CameraConfig = CameraConfig()
    obs_mode: str = "depth"  # 'depth' [H,W,1] | 'color' [H,W,3] | 'rgbd' [H,W,4]
    dynamics: str = "cw"  # 'cw' (Clohessy-Wiltshire + torque-free attitude) | 'kinematic' (original benchmark)
    targets: tuple[str, ...] = targets_lib.TRAIN_TARGETS  # catalogue names or MJCF paths, each maybe NAME@<radius>m
    frame_history: int = 1  # frames kept for averaging blur (EnvParams.blur_frames <= this)
    autoreset: str = "same_step"  # 'same_step' | 'next_step'
    final_obs_in_info: bool = True  # same_step only: render the final frame too
    attitude_substeps: int = 4

    def __post_init__(self):
        if not isinstance(self.camera, CameraConfig):
            raise ValueError(f"camera must be a render.CameraConfig, got {type(self.camera).__name__}")
        if self.obs_mode not in OBS_CHANNELS:
            raise ValueError(f"obs_mode must be one of {sorted(OBS_CHANNELS)}, got {self.obs_mode!r}")
        if self.dynamics not in ("cw", "kinematic"):
            raise ValueError(f"dynamics must be 'cw' or 'kinematic', got {self.dynamics!r}")
        if self.autoreset not in ("same_step", "next_step"):
            raise ValueError(f"autoreset must be 'same_step' or 'next_step', got {self.autoreset!r}")
        if not (isinstance(self.frame_history, int) and 1 <= self.frame_history <= 16):
            raise ValueError(f"frame_history must be an int in [1, 16], got {self.frame_history!r}")
        if isinstance(self.targets, str):
            object.__setattr__(self, "targets", (self.targets,))
        if len(self.targets) == 0:
            raise ValueError("targets must name at least one target")
        object.__setattr__(self, "targets", tuple(str(t) for t in self.targets))
        for t in self.targets:
            targets_lib.resolve(t)  # raises TargetError (a ValueError) for unknown names / missing files

    @property
    def obs_shape(self) -> tuple[int, int, int]:
        r = self.camera.resolution
        return (r, r, OBS_CHANNELS[self.obs_mode])


@struct.dataclass
class EnvParams:
    """Every physical value of the task (traced: vmap over these for domain randomisation).

    Defaults are the original benchmark's training values; evaluation uses dist_weight=1, lost_patience=20, no
    size randomisation and the default speed rule (evaluation.rollouts.EVAL_FIELDS).
    """

    catalogue: targets_lib.TargetModel  # [N, G, ...] targets an episode draws from
    target_probs: jax.Array  # [N] probability of each catalogue target at reset (one-hot pins a target)
    dt: jax.Array = 0.1  # s per step
    speed: jax.Array = 1.0  # m/s per unit action
    actuator_tau: jax.Array = 0.0  # s, first-order lag of the chaser velocity (0 = instant)
    dist_weight: jax.Array = 0.5
    lost_patience: jax.Array = 10  # terminate after more than this many consecutive lost steps
    max_steps: jax.Array = 1000  # truncation
    lost_distance: jax.Array = 15.0  # m from the desired position counts as lost
    desired_pos: jax.Array = struct.field(default_factory=lambda: jnp.array([0.0, 0.0, 5.0]))
    # Stand-off scale k of an episode's target (env.standoff_scale, from its bounding radius R): the episode's
    # lengths (desired position, start positions, lost distance, near and far plane) are scaled by k.
    # Large targets: k = max(1, standoff_per_radius * R / desired_pos[2]), held at least two bounding radii away
    # (a 12 m satellite at 24 m). Small targets (R < standoff_min_radius): k = max(standoff_min_scale,
    # R / standoff_min_radius), held closer so that they fill the view like a standoff_min_radius target at 5 m
    # (a 0.3 m cubesat at 3 m), never closer than standoff_min_scale * 5 m. Every catalogue target (bounding radius
    # 0.56-2.4 m) keeps k = 1. Target velocities are not scaled. The chaser's command speed is
    # speed * max(1, k) ** speed_standoff_power. With power 0 it is the same in m/s for every target: relative to
    # its stand-off the chaser is slower at a large target. With 1 a target held farther than nominal (k > 1) gets
    # k times the speed, the same share of its stand-off per second as a catalogue target; a small target keeps the
    # nominal speed, which it needs to follow the targets' drift (at 0.6 m/s the ceiling loses a 0.3 m target).
    standoff_per_radius: jax.Array = 2.0
    standoff_min_radius: jax.Array = 0.5  # m
    standoff_min_scale: jax.Array = 0.3  # floor of k (in (0, 1])
    speed_standoff_power: jax.Array = 1.0  # in [0, 1]; an evaluation field (evaluation.rollouts.EVAL_FIELDS)
    # A small target's (k < 1) command speed and drift (initial velocity and acceleration) times k ** this power: 1
    # makes its dynamics the catalogue's in stand-off units (a diagnostic; 0, physical speeds, the default).
    small_standoff_power: jax.Array = 0.0  # in [0, 1]; an evaluation field
    # Size randomisation (training): each episode's target geometry times a factor drawn log-uniformly from
    # [size_scale_min, size_scale_max] (1, 1: off, the default) in a share size_scale_prob of the episodes; the
    # stand-off rule then applies to the scaled radius. Evaluation keeps the models' own sizes
    # (evaluation.rollouts.EVAL_FIELDS).
    size_scale_min: jax.Array = 1.0
    size_scale_max: jax.Array = 1.0
    size_scale_prob: jax.Array = 1.0  # share of episodes resized; the others keep the model's own size
    # Shape randomisation (training): in a share stretch_prob of the episodes the target is stretched along its
    # principal axes (targets.stretched), with log factors drawn uniformly in [-ln stretch_max, ln stretch_max] per
    # axis and then centred, so that the volume is kept (size is size_scale's concern): each factor lies in
    # [stretch_max ** (-4/3), stretch_max ** (4/3)]. The stand-off rule applies to the stretched bounding radius (a
    # catalogue model stretched past 2.5 m is held farther). stretch_max 1 is off (the default); evaluation keeps
    # the models' own shapes (evaluation.rollouts.EVAL_FIELDS).
    stretch_max: jax.Array = 1.0
    stretch_prob: jax.Array = 1.0
    # Centre-offset randomisation (training): in a share offset_prob of the episodes the target's geometry is moved
    # off its centre of mass, the tracked point it spins about (targets.shifted), by a vector drawn uniformly in a
    # ball of offset_max times its bounding radius, so the centre of what the camera sees is not the centre to hold
    # and only the rotation tells where that is (mass and inertia kept: a modelling shortcut; the centre may even
    # lie outside a sparse model's geoms). The stand-off is the unshifted target's. 0 is off (the default);
    # evaluation flies the models as they are (evaluation.rollouts.EVAL_FIELDS).
    offset_max: jax.Array = 0.0
    offset_prob: jax.Array = 1.0
    # The start distribution (env.TrackingEnv.initial_state); training may widen it, evaluation flies these values
    # (evaluation.rollouts.EVAL_FIELDS).
    init_xy_std: jax.Array = 1.0  # m
    init_z_min: jax.Array = 2.0  # m
    init_z_max: jax.Array = 12.0  # m
    target_vel_std: jax.Array = 0.2  # m/s per axis
    target_spin_std: jax.Array = 0.1  # rad/s per body axis
    target_accel_std: jax.Array = 0.0  # m/s^2 per axis, constant thrust of a maneuvering target
    mean_motion: jax.Array = dynamics.mean_motion(400e3)  # rad/s of the reference orbit
    # perturbations (0 = off); original values: actuator 0.3, delay 0.5 s, blur 3-frame average
    actuator_noise: jax.Array = 0.0  # command * (1 + actuator_noise * N(0, 1)) per axis
    delay_max: jax.Array = 0.0  # each step lasts dt + U(0, delay_max) s
    blur_frames: jax.Array = 1  # observation = mean of the last blur_frames frames (<= EnvConfig.frame_history)
    gaussian_blur_sigma: jax.Array = 0.0  # px
    motion_blur_px: jax.Array = 0.0  # px, along the image-plane direction of the relative motion
    depth_noise_std: jax.Array = 0.0  # additive noise on target pixels (in observation units)
    frame_drop_prob: jax.Array = 0.0  # probability that the camera repeats its previous frame
    # Perturbation randomisation (training): each of the three perturbations above that is configured (actuator
    # noise, time delay, frame-averaging blur) is applied in an episode with this probability, drawn per
    # perturbation and episode (randomisation.perturbed); 1, the default, applies them in every episode. Evaluation
    # sets these four fields itself (evaluation.rollouts.EVAL_FIELDS): a Table II setting is on in every episode.
    perturb_prob: jax.Array = 1.0
    sun_dir: jax.Array = struct.field(default_factory=lambda: jnp.array([0.5, -0.6, -0.62]) / 0.9993)
    ambient: jax.Array = 0.15


# The range of every traced setting: {name: (low, high, what)}, the bounds included unless `what` says "(" or ")".
# Wide enough for every preset and the evaluation settings (Table II: actuator noise 0.3, a delay of up to 0.5 s, a
# 3-frame blur), narrow enough that the task stays the one the docs describe: a chaser holding a target a few
# metres ahead in view, stepped at a few hertz, on a near-circular orbit. The camera-dependent bounds (init_z_min,
# blur_frames, the blurs, desired_pos) are checked against the EnvConfig.
RANGES: dict[str, tuple[float, float, str]] = {
    "dt": (0.0, 1.0, "in (0, 1] s (a step of the control loop)"),
    "speed": (0.0, 10.0, "in (0, 10] m/s per unit command"),
    "actuator_tau": (0.0, 10.0, "in [0, 10] s (0: instant)"),
    "dist_weight": (0.0, 10.0, "in [0, 10] (reward per metre off the desired position)"),
    "lost_patience": (0, 100_000, "a whole number in [0, 100000] steps"),
    "max_steps": (1, 1_000_000, "a whole number in [1, 1000000] steps"),
    "lost_distance": (0.0, 1000.0, "in (0, 1000] m"),
    "standoff_per_radius": (0.0, 100.0, "in (0, 100] (stand-off per bounding radius)"),
    "standoff_min_radius": (0.0, 100.0, "in (0, 100] m"),
    "standoff_min_scale": (0.0, 1.0, "in (0, 1]"),
    "speed_standoff_power": (0.0, 1.0, "in [0, 1]"),
    "small_standoff_power": (0.0, 1.0, "in [0, 1]"),
    "size_scale_min": (0.01, 100.0, "in [0.01, 100] (a size factor)"),
    "size_scale_max": (0.01, 100.0, "in [0.01, 100] (a size factor)"),
    "size_scale_prob": (0.0, 1.0, "in [0, 1]"),
    "stretch_max": (1.0, 10.0, ">= 1 (1: off) and <= 10"),
    "stretch_prob": (0.0, 1.0, "in [0, 1]"),
    "offset_max": (0.0, 1.0, "in [0, 1] (bounding radii; 0: off)"),
    "offset_prob": (0.0, 1.0, "in [0, 1]"),
    "init_xy_std": (0.0, 100.0, "in [0, 100] m"),
    "init_z_min": (0.0, 1000.0, "in (camera.near, 1000] m"),
    "init_z_max": (0.0, 1000.0, "in (camera.near, 1000] m"),
    "target_vel_std": (0.0, 10.0, "in [0, 10] m/s"),
    "target_spin_std": (0.0, 10.0, "in [0, 10] rad/s"),
    "target_accel_std": (0.0, 10.0, "in [0, 10] m/s^2"),
    "mean_motion": (0.0, 0.01, "in [0, 0.01] rad/s (an orbit of 10 minutes or longer; 0.00113 at 400 km)"),
    "actuator_noise": (0.0, 10.0, "in [0, 10]"),
    "delay_max": (0.0, 10.0, "in [0, 10] s"),
    "blur_frames": (1, 16, "a whole number in [1, EnvConfig.frame_history]"),
    "gaussian_blur_sigma": (0.0, 1024.0, "in [0, camera.resolution] px"),
    "motion_blur_px": (0.0, 1024.0, "in [0, camera.resolution] px"),
    "depth_noise_std": (0.0, 1.0, "in [0, 1] (observation units)"),
    "frame_drop_prob": (0.0, 1.0, "in [0, 1]"),
    "perturb_prob": (0.0, 1.0, "in [0, 1]"),
    "ambient": (0.0, 1.0, "in [0, 1]"),
}
_WHOLE = ("lost_patience", "max_steps", "blur_frames")


def _defaults() -> dict:
    """EnvParams' default values by name (catalogue and target_probs, which have none, left out)."""
    out = {}
    for f in dataclasses.fields(EnvParams):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
    return out


def _check_values(values: dict, names, config: EnvConfig | None, owner: str) -> None:
    """The checks of :func:`validate_params` on the settings ``names`` of ``values`` (every setting by name, as
    numpy arrays); ``config`` None skips the camera-dependent bounds. Raises ValueError naming the first."""

    def fail(name, what):
        raise ValueError(f"{owner}{name} must be {what}, got {values[name]}")

    for name in names:
        v = values[name]
        if not (v.dtype.kind in "biuf" and np.isfinite(v).all()):
            fail(name, "finite numbers")
        if name in RANGES:
            lo, hi, what = RANGES[name]
            if what.startswith("in (camera.near"):
                lo = config.camera.near if config is not None else 0.0
            if name == "blur_frames" and config is not None:
                hi = config.frame_history
            if name in ("gaussian_blur_sigma", "motion_blur_px") and config is not None:
                hi = config.camera.resolution
            open_low = what.startswith("in (")
            if not (np.all((v > lo) if open_low else (v >= lo)) and np.all(v <= hi)):
                if config is not None:
                    what = what.replace("camera.near", f"camera.near={lo:g}").replace(
                        "camera.resolution", f"camera.resolution={hi:g}"
                    )
                fail(name, what.replace("EnvConfig.frame_history", f"EnvConfig.frame_history={hi}"))
            if name in _WHOLE and not np.all(v == np.round(v)):
                fail(name, what)
    pairs = (("size_scale_max", "size_scale_min", ">="), ("init_z_max", "init_z_min", ">"))
    for high, low, op in pairs:  # both given (overrides given alone may join a preset's later: `--preset sizes`)
        if high in names and low in names:
            if not np.all(values[high] >= values[low] if op == ">=" else values[high] > values[low]):
                fail(high, f"{op} {low} ({values[low]})")
    if "sun_dir" in names:
        v = values["sun_dir"]
        if v.shape != (3,) or not np.linalg.norm(v) > 0:
            fail("sun_dir", "a direction: 3 numbers, not all 0")
    if "desired_pos" in names:
        v = values["desired_pos"]
        if v.shape != (3,) or not v[2] > 0:
            fail("desired_pos", "3 numbers [x, y, z] in metres with z > 0 (ahead of the camera)")
        if config is not None:
            cam = config.camera
            edge = float(v[2]) * np.tan(np.deg2rad(cam.fov_deg) / 2.0)
            if not (cam.near < v[2] < cam.far and abs(v[0]) <= edge and abs(v[1]) <= edge):
                fail(
                    "desired_pos",
                    f"in view: z in ({cam.near:g}, {cam.far:g}) m (camera.near, camera.far), |x| and |y| <= z * "
                    f"tan(fov / 2)",
                )
    if "target_probs" in names and config is not None:
        v = values["target_probs"]
        if not (v.shape == (len(config.targets),) and (v >= 0).all() and abs(v.sum() - 1) < 1e-4):
            fail("target_probs", f"[{len(config.targets)}] non-negative probabilities summing to 1")


def check_settings(overrides: dict, config: EnvConfig | None = None, owner: str = "EnvParams.") -> None:
    """Check EnvParams overrides ``{name: value}`` before any params are built: the ranges of :data:`RANGES` and the
    relations of the settings given together (size_scale_max >= size_scale_min, ...; those of a setting given alone
    are checked with the built params); ``config``: the camera-dependent bounds too. Raises ValueError in one line
    naming the setting and its range."""
    values = {k: np.asarray(v) for k, v in {**_defaults(), **overrides}.items()}
    _check_values(values, [k for k in overrides if k not in ("catalogue",)], config, owner)


def validate_params(params: EnvParams, config: EnvConfig) -> EnvParams:
    """Host-side checks of concrete parameter values (skipped for traced values): every setting in its range
    (:data:`RANGES`). Raises ValueError naming the setting and its range."""
    values = {}
    for field in dataclasses.fields(params):
        if field.name == "catalogue":
            continue
        try:
            values[field.name] = np.asarray(getattr(params, field.name))
        except Exception:  # traced inside jit: nothing to check
            continue
    _check_values(values, list(values), config, "EnvParams.")
    return params
