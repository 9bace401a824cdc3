"""The tracking environment: a chaser with a body-fixed camera keeps a tumbling target 5 m in front of it.

Functional, gymnax-1.0-style API on a static env object::

    tracking_env = env.TrackingEnv(env.EnvConfig())          # static: resolution, obs mode, dynamics mode
    params = tracking_env.default_params()                     # traced: every physical value + the target catalogue
    obs, state = tracking_env.reset(key, params)
    obs, state, reward, terminated, truncated, info = tracking_env.step(key, state, action, params)

Frames. All states live in the Hill (LVLH) frame of a circular reference orbit through the chaser's starting point:
x radial (outward), y along-track, z orbit normal. The camera does not rotate relative to Hill; its axes are
x_cam = -z_hill, y_cam = -x_hill (down = towards Earth), z_cam = +y_hill (boresight along-track, a V-bar approach).
Velocity commands and observations are in the camera frame.

Auto-reset. ``autoreset='same_step'`` (gymnax): a step that ends an episode returns the first observation of a
freshly drawn episode and keeps the final one in ``info['final_observation']`` (two renders on those steps when
``final_obs_in_info``). ``autoreset='next_step'`` (gymnasium vector / envpool): the step that ends an episode returns
its real final observation; the next call starts the new episode (reward 0, ``info['is_first']``) and its action is
ignored. Every observation is rendered once, which is what the trainer uses.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ramavt_jax import dynamics, randomisation, render
from ramavt_jax import targets as targets_lib
from ramavt_jax.env_config import (  # noqa: F401 (re-exported: env.EnvConfig, env.ACTIONS, ... are the public names)
    ACTIONS,
    HILL_FROM_CAM,
    NUM_ACTIONS,
    OBS_CHANNELS,
    RETREAT,
    EnvConfig,
    EnvParams,
    validate_params,
)
from ramavt_jax.render import CameraConfig, Lighting


@struct.dataclass
class EnvState:
    """One env's state. Positions/velocities [3] in the Hill frame; quat [4] scalar-first inertial_from_body."""

    target: targets_lib.TargetModel  # geometry of this episode's target, [G, ...]
    target_index: jax.Array  # [] index into the catalogue
    target_pos: jax.Array
    target_vel: jax.Array
    target_accel: jax.Array
    target_quat: jax.Array
    target_omega: jax.Array  # [3] body frame
    chaser_pos: jax.Array
    chaser_vel: jax.Array
    sim_time: jax.Array  # [] s since the episode start (with delays): the Hill frame has turned by n * sim_time
    frames: jax.Array  # [K, H, W, C] newest last
    lost_steps: jax.Array  # [] consecutive steps without the target
    steps: jax.Array  # [] steps taken this episode
    episode_return: jax.Array  # []
    done: jax.Array  # [] bool, the last step ended the episode (used by next_step autoreset)
    scale: jax.Array  # [] stand-off scale k of this episode's target (standoff_scale; 1 for every catalogue target)
    perturbed: jax.Array  # [3] 1.0 where this episode has actuator noise, time delay, blur (randomisation.perturbed)


@struct.dataclass
class Pose:
    """Target pose seen from the camera: position [3] of its centre of mass, rotation [3, 3] camera_from_body."""

    position: jax.Array
    rotation: jax.Array


def _rot_z(angle: jax.Array) -> jax.Array:
    c, s = jnp.cos(angle), jnp.sin(angle)
    z, o = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.array([[c, -s, z], [s, c, z], [z, z, o]])


def relative_position(state: EnvState) -> jax.Array:
    """Target centre in the camera frame [3]."""
    return HILL_FROM_CAM.T @ (state.target_pos - state.chaser_pos)


def standoff_scale(target: targets_lib.TargetModel, params: EnvParams) -> jax.Array:
    """[] Stand-off scale k of a target with bounding radius R (see EnvParams.standoff_per_radius): for R >=
    standoff_min_radius k = max(1, standoff_per_radius * R / desired distance), held far enough to fit the view; below
    it k = max(standoff_min_scale, R / standoff_min_radius), held closer to fill the view like a standoff_min_radius
    target at 5 m. k is exactly 1.0 for R in 0.5-2.5 m by default, which holds every catalogue target."""
    radius = target.bound_radius
    large = jnp.maximum(1.0, params.standoff_per_radius * radius / params.desired_pos[2])
    small = jnp.maximum(params.standoff_min_scale, radius / params.standoff_min_radius)
    return jnp.where(radius < params.standoff_min_radius, small, large)


# The draws of an episode's start, each from its own key (episode_keys): the target, its start (position across and
# along the view, velocity, acceleration, attitude, spin), and the domain randomisation (randomisation.py).
EPISODE_DRAWS = (
    "target",
    "xy",
    "z",
    "velocity",
    "attitude",
    "spin",
    "acceleration",
    "stretch",
    "size",
    "offset",
    "perturbed",
)


def episode_keys(key: jax.Array) -> dict[str, jax.Array]:
    """{draw: key} for each of EPISODE_DRAWS, split from an episode's key (TrackingEnv.initial_state's)."""
    return dict(zip(EPISODE_DRAWS, jax.random.split(key, len(EPISODE_DRAWS))))


def command_speed(state: EnvState, params: EnvParams) -> jax.Array:
    """[] m/s per unit action: speed * max(1, k) ** speed_standoff_power * min(1, k) ** small_standoff_power."""
    large, small = jnp.maximum(state.scale, 1.0), jnp.minimum(state.scale, 1.0)
    return params.speed * large**params.speed_standoff_power * small**params.small_standoff_power


def desired_position(state: EnvState, params: EnvParams) -> jax.Array:
    """Where the target centre should be in the camera frame [3] for this episode's target (m)."""
    return params.desired_pos * state.scale


def state_rotation(state: EnvState, mean_motion: jax.Array) -> jax.Array:
    """camera_from_body [3, 3]: the attitude is inertial; the Hill frame has turned by n * t since the start."""
    hill_from_inertial = _rot_z(-mean_motion * state.sim_time)
    return HILL_FROM_CAM.T @ hill_from_inertial @ dynamics.quat_to_mat(state.target_quat)


def _where(condition: jax.Array, on_true, on_false):
    """Select between two pytrees of the same structure with a scalar condition."""
    return jax.tree.map(lambda a, b: jnp.where(condition, a, b), on_true, on_false)


def in_view(position: jax.Array, camera: CameraConfig) -> jax.Array:
    """Whether a camera-frame point [3] projects inside the image and lies in front of the near plane. The env
    passes the position divided by the stand-off scale k, as it renders: the near plane is k * camera.near away."""
    tan_half, z = jnp.tan(jnp.deg2rad(camera.fov_deg) / 2.0), position[2]
    safe_z = jnp.where(z > camera.near, z, 1.0)
    return (z > camera.near) & (jnp.abs(position[0] / safe_z) <= tan_half) & (jnp.abs(position[1] / safe_z) <= tan_half)


def reward_fn(position: jax.Array, visible: jax.Array, params: EnvParams, scale: jax.Array = 1.0) -> jax.Array:
    """+1 if the target centre is in view else -5, minus dist_weight * ||r* - p|| (original SNCOAT reward).
    For a target held at a scaled stand-off (scale k != 1) the distance is measured in units of k metres, so the
    reward means the same for every target size; k = 1 is the original reward exactly."""
    return jnp.where(visible, 1.0, -5.0) - params.dist_weight * jnp.linalg.norm(params.desired_pos - position / scale)


def _param_array(name: str, value) -> jax.Array:
    """An EnvParams override as an array; ValueError naming the field for a value that is not numeric."""
    if isinstance(value, jax.Array):
        return value
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"EnvParams.{name} must be a number (or an array of numbers), got {value!r}")
    return jnp.asarray(arr)


class TrackingEnv:
    """Static env object; all methods are pure functions of their arguments (jit/vmap them freely)."""

    def __init__(self, config: EnvConfig = EnvConfig()):
        self.config = config

    # Equal configs make equal envs (it holds nothing else): compiled-rollout caches keyed on the env are shared.
    def __eq__(self, other) -> bool:
        return type(other) is type(self) and other.config == self.config

    def __hash__(self) -> int:
        return hash((type(self), self.config))

    # ----------------------------------------------------------------------------------------- parameters
    def default_params(self, **overrides: Any) -> EnvParams:
        """Original training values with this config's targets loaded; keyword overrides replace fields."""
        catalogue, num = targets_lib.load_many(self.config.targets)[0], len(self.config.targets)
        params = EnvParams(catalogue=catalogue, target_probs=jnp.full((num,), 1.0 / num))
        params = params.replace(**{k: _param_array(k, v) for k, v in overrides.items()}) if overrides else params
        return validate_params(params, self.config)

    def pinned(self, params: EnvParams, target: int | str) -> EnvParams:
        """Params whose episodes all use one target (by index or name in EnvConfig.targets)."""
        index = self.config.targets.index(target) if isinstance(target, str) else int(target)
        return params.replace(target_probs=jax.nn.one_hot(index, len(self.config.targets)))

    def eval_params(self, **overrides: Any) -> EnvParams:
        """The reported-table settings: reward weight 1, lost patience 20, 1000 steps."""
        return self.default_params(**{"dist_weight": 1.0, "lost_patience": 20, **overrides})

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    @property
    def observation_shape(self) -> tuple[int, int, int]:
        return self.config.obs_shape

    # ----------------------------------------------------------------------------------------- reset
    def reset(self, key: jax.Array, params: EnvParams) -> tuple[jax.Array, EnvState]:
        """Draw a fresh episode. Returns (obs [H, W, C], state)."""
        k_state, k_obs = jax.random.split(key)
        state = self.initial_state(k_state, params)
        return self._postprocess(k_obs, self._render(state, params), state, params, first=jnp.ones((), bool))

    def initial_state(self, key: jax.Array, params: EnvParams) -> EnvState:
        """Initial distribution (original values): target at x,y ~ N(0, 1), z ~ U[2, 12) m in the camera frame,
        times the stand-off scale k of the episode's target (standoff_scale, after randomisation.stretch and
        size_factor, before randomisation.shift), velocity N(0, 0.2) m/s, random orientation, spin N(0, 0.1) rad/s
        per body axis; chaser at rest at the origin. Frame history zeros (``reset`` fills it with the first obs)."""
        k = episode_keys(key)
        index = jax.random.categorical(k["target"], jnp.log(params.target_probs))
        target = randomisation.stretch(k["stretch"], targets_lib.select(params.catalogue, index), params)
        target = targets_lib.scaled(target, randomisation.size_factor(k["size"], params))
        scale = standoff_scale(target, params)
        target = randomisation.shift(k["offset"], target, params)  # after the stand-off: k is the unshifted target's
        xy = params.init_xy_std * jax.random.normal(k["xy"], (2,))
        z = jax.random.uniform(k["z"], (), minval=params.init_z_min, maxval=params.init_z_max)
        pos_cam = jnp.array([xy[0], xy[1], z]) * scale
        drift = jnp.minimum(scale, 1.0) ** params.small_standoff_power  # 1: a small target's, in stand-off units
        vel_cam = params.target_vel_std * jax.random.normal(k["velocity"], (3,)) * drift
        accel_cam = params.target_accel_std * jax.random.normal(k["acceleration"], (3,)) * drift
        r, c = self.config.camera.resolution, OBS_CHANNELS[self.config.obs_mode]
        zero = jnp.zeros(3)
        return EnvState(
            target=target,
            target_index=index,
            target_pos=HILL_FROM_CAM @ pos_cam,
            target_vel=HILL_FROM_CAM @ vel_cam,
            target_accel=HILL_FROM_CAM @ accel_cam,
            target_quat=dynamics.random_quaternion(k["attitude"]),
            target_omega=params.target_spin_std * jax.random.normal(k["spin"], (3,)),
            chaser_pos=zero,
            chaser_vel=zero,
            sim_time=jnp.zeros(()),
            frames=jnp.zeros((self.config.frame_history, r, r, c)),
            lost_steps=jnp.zeros((), jnp.int32),
            steps=jnp.zeros((), jnp.int32),
            episode_return=jnp.zeros(()),
            done=jnp.zeros((), bool),
            scale=scale,
            perturbed=randomisation.perturbed(k["perturbed"], params),
        )

    # ----------------------------------------------------------------------------------------- step
    def transition(self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams) -> EnvState:
        """Physics only: apply the velocity command and advance target and chaser by one (possibly delayed) step."""
        k_noise, k_delay = jax.random.split(key)
        command_cam = jnp.asarray(ACTIONS)[action] * command_speed(state, params)
        on, noise = state.perturbed > 0, 1.0 + params.actuator_noise * jax.random.normal(k_noise, (3,))
        command_cam = command_cam * jnp.where(on[0], noise, 1.0)  # an episode without the noise flies the command
        duration = jnp.where(on[1], params.dt + params.delay_max * jax.random.uniform(k_delay, ()), params.dt)
        command = HILL_FROM_CAM @ command_cam

        # Chaser: first-order velocity lag (tau = 0 is instant), trapezoidal position update.
        safe_tau = jnp.where(params.actuator_tau > 0, params.actuator_tau, 1.0)
        blend = jnp.where(params.actuator_tau > 0, jnp.exp(-duration / safe_tau), 0.0)
        chaser_vel = command + (state.chaser_vel - command) * blend
        chaser_pos = state.chaser_pos + 0.5 * (state.chaser_vel + chaser_vel) * duration

        if self.config.dynamics == "cw":
            target_pos, target_vel = dynamics.cw_step(
                state.target_pos, state.target_vel, state.target_accel, params.mean_motion, duration
            )
        else:
            target_pos, target_vel = dynamics.kinematic_step(state.target_pos, state.target_vel, duration)
        quat, omega = dynamics.attitude_step(
            state.target_quat, state.target_omega, state.target.inertia, duration, self.config.attitude_substeps
        )
        return state.replace(
            target_pos=target_pos,
            target_vel=target_vel,
            target_quat=quat,
            target_omega=omega,
            chaser_pos=chaser_pos,
            chaser_vel=chaser_vel,
            sim_time=state.sim_time + duration,
        )

    def score(self, state: EnvState, params: EnvParams) -> tuple[EnvState, jax.Array, jax.Array, jax.Array, dict]:
        """Reward and episode end for a state just reached. Returns (state, reward, terminated, truncated, info)."""
        position = relative_position(state)
        visible = in_view(position / state.scale, self.config.camera)
        error = position - desired_position(state, params)
        lost = ~visible | (jnp.linalg.norm(error) > params.lost_distance * state.scale)
        lost_steps = jnp.where(lost, state.lost_steps + 1, 0)
        reward = reward_fn(position, visible, params, state.scale)
        steps = state.steps + 1
        terminated = lost_steps > params.lost_patience
        truncated = (steps >= params.max_steps) & ~terminated
        state = state.replace(
            lost_steps=lost_steps,
            steps=steps,
            episode_return=state.episode_return + reward,
            done=terminated | truncated,
        )
        info = dict(
            rel_pos=position,
            tracking_error=error,
            in_view=visible,
            lost=lost,
            target_index=state.target_index,
            episode_return=state.episode_return,
            episode_length=steps,
            is_first=jnp.zeros((), bool),
        )
        return state, reward, terminated, truncated, info

    def step_env(self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams):
        """One step without auto-reset. Returns (obs, state, reward, terminated, truncated, info)."""
        k_phys, k_obs = jax.random.split(key)
        state = self.transition(k_phys, state, action, params)
        state, reward, terminated, truncated, info = self.score(state, params)
        frame = self._render(state, params)
        obs, state = self._postprocess(k_obs, frame, state, params)
        return obs, state, reward, terminated, truncated, info

    def step(self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams):
        """One step with auto-reset (see module docstring for the two modes).

        Returns (obs [H, W, C], state, reward [], terminated [] bool, truncated [] bool, info dict).
        """
        k_phys, k_obs, k_reset, k_first = jax.random.split(key, 4)
        fresh = self.initial_state(k_reset, params)
        moved = self.transition(k_phys, state, action, params)
        moved, reward, terminated, truncated, info = self.score(moved, params)
        if self.config.autoreset == "next_step":
            restart = state.done
            chosen = _where(restart, fresh, moved)
            obs, chosen = self._postprocess(k_obs, self._render(chosen, params), chosen, params, first=restart)
            first_info = self._first_info(chosen, params)
            info = _where(restart, first_info, info)
            zero = jnp.zeros((), bool)
            return (
                obs,
                chosen,
                jnp.where(restart, 0.0, reward),
                jnp.where(restart, zero, terminated),
                jnp.where(restart, zero, truncated),
                info,
            )

        done = terminated | truncated
        if self.config.final_obs_in_info:
            final_obs, moved = self._postprocess(k_obs, self._render(moved, params), moved, params)
            # Only finished envs need the new episode's frame; the others are culled (no tile is cast for them).
            first_frame = self._render(fresh, params, visible=done)
            first_obs, fresh = self._postprocess(k_first, first_frame, fresh, params, first=jnp.ones((), bool))
            info["final_observation"] = final_obs
            return (
                jnp.where(done, first_obs, final_obs),
                _where(done, fresh, moved),
                reward,
                terminated,
                truncated,
                info,
            )
        # One render per step: a finished env draws only its new episode's first frame.
        chosen = _where(done, fresh, moved)
        obs, chosen = self._postprocess(k_obs, self._render(chosen, params), chosen, params, first=done)
        return obs, chosen, reward, terminated, truncated, info

    def _first_info(self, state: EnvState, params: EnvParams) -> dict:
        position = relative_position(state)
        return dict(
            rel_pos=position,
            tracking_error=position - desired_position(state, params),
            in_view=in_view(position / state.scale, self.config.camera),
            lost=jnp.zeros((), bool),
            target_index=state.target_index,
            episode_return=jnp.zeros(()),
            episode_length=jnp.zeros((), jnp.int32),
            is_first=jnp.ones((), bool),
        )

    # ----------------------------------------------------------------------------------------- observation
    def pose(self, state: EnvState, params: EnvParams) -> Pose:
        return Pose(position=relative_position(state), rotation=state_rotation(state, params.mean_motion))

    def lighting(self, params: EnvParams) -> Lighting:
        sun = params.sun_dir / jnp.linalg.norm(params.sun_dir)
        return Lighting(sun_dir=sun, ambient=jnp.asarray(params.ambient, jnp.float32))

    def _render(self, state: EnvState, params: EnvParams, visible: jax.Array | None = None) -> render.Frame:
        """Camera frame of `state`; where `visible` is False the target is moved behind the camera, which the
        renderer's culling skips at almost no cost (used for frames that will be discarded).

        A target at stand-off scale k is rendered scaled by 1 / k at 1 / k of its distance: the same image, with
        depths divided by k, i.e. near and far planes k times farther (exact: multiplying by 1.0 changes no float).
        For k < 1 the near plane is k * camera.near away, and a start at k * init_z_min stays in front of it."""
        pose = self.pose(state, params)
        position = pose.position / state.scale
        if visible is not None:
            position = jnp.where(visible, position, jnp.array([0.0, 0.0, -1e6]))
        shade = self.config.obs_mode != "depth"
        target = targets_lib.scaled(state.target, 1.0 / state.scale)
        return render.render(target, position, pose.rotation, self.config.camera, self.lighting(params), shade)

    def _postprocess(self, key, frame: render.Frame, state: EnvState, params: EnvParams, first=None):
        """Image perturbations and the frame history. Returns (obs [H, W, C], state with the new frame pushed)."""
        k_noise, k_drop = jax.random.split(key)
        image = render.to_observation(frame, self.config.obs_mode, self.config.camera.far)
        image = render.gaussian_blur(image, params.gaussian_blur_sigma)
        velocity_img = (HILL_FROM_CAM.T @ (state.target_vel - state.chaser_vel))[:2]  # streak direction
        image = render.motion_blur(image, params.motion_blur_px, jnp.arctan2(velocity_img[1], velocity_img[0]))
        # Same draws as jax.random.normal(k_noise, image.shape), but none at all when the noise is off: drawing a
        # normal per pixel was a third of a 64x64 depth env step (benchmarks/RESULTS.md).
        image = render.add_noise(k_noise, image, params.depth_noise_std, frame.hit[..., None])
        dropped = jax.random.uniform(k_drop, ()) < params.frame_drop_prob
        if first is not None:
            dropped = dropped & ~first
        image = jnp.where(dropped, state.frames[-1], image)
        frames = jnp.concatenate([state.frames[1:], image[None]], axis=0)
        if first is not None:  # a new episode starts with a history full of its first frame
            frames = jnp.where(first, jnp.broadcast_to(image, frames.shape), frames)
        k = frames.shape[0]
        blur_frames = jnp.where(state.perturbed[2] > 0, params.blur_frames, 1)
        weights = (jnp.arange(k) >= k - blur_frames).astype(image.dtype)
        if k == 1:  # no averaging blur possible: the frame itself (the same value, without the weighted sum)
            return frames[0], state.replace(frames=frames)
        obs = jnp.tensordot(weights / weights.sum(), frames, axes=1)
        return obs, state.replace(frames=frames)
