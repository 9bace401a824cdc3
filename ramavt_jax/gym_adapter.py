"""Gymnasium adapters: a single `gymnasium.Env` and a `gymnasium.vector.VectorEnv` over the vmapped batch.

For users of the gymnasium API; the functional API in `ramavt_jax.env` is what the trainer uses. Observations are
float32 arrays in [0, 1] of shape [H, W, C] (vector: [N, H, W, C]); actions are integers 0..10.

Registered ids (importing this module registers them; ``gymnasium.make("ramavt_jax.gym_adapter:Tracking-v0")``
imports it itself)::

    env = gymnasium.make("ramavt_jax/Tracking-v0", config=EnvConfig(...))          # TrackingGymEnv
    vec = gymnasium.make_vec("ramavt_jax/Tracking-v0", num_envs=8, vectorization_mode="vector_entry_point")
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces

from ramavt_jax import env as env_lib
from ramavt_jax import render

ENV_ID = "ramavt_jax/Tracking-v0"


def _info_to_numpy(info: dict) -> dict[str, Any]:
    return {k: np.asarray(v) for k, v in info.items()}


def _is_integer(x) -> bool:
    """A Python or numpy integer (0-d integer arrays too); bools, floats and strings are not actions."""
    if isinstance(x, (bool, np.bool_)):
        return False
    if isinstance(x, (int, np.integer)):
        return True
    return isinstance(x, (np.ndarray, jax.Array)) and x.shape == () and np.issubdtype(x.dtype, np.integer)


def check_actions(actions: np.ndarray) -> None:
    """Integer actions in [0, NUM_ACTIONS); a clear ValueError naming the bad value otherwise."""
    n = env_lib.NUM_ACTIONS
    if not np.issubdtype(actions.dtype, np.integer) or actions.dtype == np.bool_:
        raise ValueError(f"actions must be integers in [0, {n - 1}], got dtype {actions.dtype}: {actions!r}")
    if actions.size and (actions.min() < 0 or actions.max() >= n):
        raise ValueError(f"actions must be integers in [0, {n - 1}], got {actions!r}")


class TrackingGymEnv(gymnasium.Env):
    """One tracking env behind the gymnasium API (terminated / truncated kept apart; no auto-reset)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        config: env_lib.EnvConfig = env_lib.EnvConfig(),
        params: env_lib.EnvParams | None = None,
        render_mode: str | None = None,
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.tracking_env = env_lib.TrackingEnv(config)
        self.params = params if params is not None else self.tracking_env.default_params()
        self.render_mode = render_mode
        self.observation_space = spaces.Box(0.0, 1.0, shape=config.obs_shape, dtype=np.float32)
        self.action_space = spaces.Discrete(env_lib.NUM_ACTIONS)
        self._reset = jax.jit(self.tracking_env.reset)
        self._step = jax.jit(self.tracking_env.step_env)
        self._key = jax.random.key(0)
        self._state = None
        self._ended = False  # the episode terminated or was truncated: only reset() may follow

    def _next_key(self) -> jax.Array:
        self._key, key = jax.random.split(self._key)
        return key

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._key = jax.random.key(seed)
        elif self._state is None:
            self._key = jax.random.key(int(self.np_random.integers(2**31)))
        obs, self._state = self._reset(self._next_key(), self.params)
        self._ended = False
        position = env_lib.relative_position(self._state)
        return np.asarray(obs, np.float32), {"rel_pos": np.asarray(position)}

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        if self._ended:  # no auto-reset here: a further step would act in an episode that is over
            raise RuntimeError("the episode has ended (terminated or truncated); call reset() before step()")
        if not _is_integer(action) or not 0 <= int(action) < env_lib.NUM_ACTIONS:
            raise ValueError(f"action must be an integer in [0, {env_lib.NUM_ACTIONS - 1}], got {action!r}")
        obs, self._state, reward, terminated, truncated, info = self._step(
            self._next_key(), self._state, jnp.asarray(int(action)), self.params
        )
        self._ended = bool(terminated) or bool(truncated)
        return np.asarray(obs, np.float32), float(reward), bool(terminated), bool(truncated), _info_to_numpy(info)

    def render(self):
        """The camera's colour view as uint8 [H, W, 3]."""
        if self._state is None:
            return None
        pose = self.tracking_env.pose(self._state, self.params)
        frame = render.render(
            self._state.target,
            pose.position,
            pose.rotation,
            self.tracking_env.config.camera,
            self.tracking_env.lighting(self.params),
            True,
        )
        return (np.asarray(frame.rgb) * 255).astype(np.uint8)


class TrackingVectorEnv(gymnasium.vector.VectorEnv):
    """`num_envs` tracking envs stepped as one vmapped, jitted call (gymnasium's NEXT_STEP auto-reset)."""

    metadata = {"autoreset_mode": gymnasium.vector.AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self, num_envs: int, config: env_lib.EnvConfig = env_lib.EnvConfig(), params: env_lib.EnvParams | None = None
    ):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        config = dataclasses.replace(config, autoreset="next_step")
        self.tracking_env = env_lib.TrackingEnv(config)
        self.params = params if params is not None else self.tracking_env.default_params()
        self.num_envs = num_envs
        self.single_observation_space = spaces.Box(0.0, 1.0, shape=config.obs_shape, dtype=np.float32)
        self.single_action_space = spaces.Discrete(env_lib.NUM_ACTIONS)
        self.observation_space = gymnasium.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gymnasium.vector.utils.batch_space(self.single_action_space, num_envs)
        self._reset = jax.jit(jax.vmap(self.tracking_env.reset, in_axes=(0, None)))
        self._step = jax.jit(jax.vmap(self.tracking_env.step, in_axes=(0, 0, 0, None)))
        self._key = jax.random.key(0)
        self._state = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._key = jax.random.key(seed)
        self._key, key = jax.random.split(self._key)
        obs, self._state = self._reset(jax.random.split(key, self.num_envs), self.params)
        return np.asarray(obs, np.float32), {}

    def step(self, actions):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs,):
            raise ValueError(f"actions must have shape ({self.num_envs},), got {actions.shape}")
        check_actions(actions)
        self._key, key = jax.random.split(self._key)
        obs, self._state, reward, terminated, truncated, info = self._step(
            jax.random.split(key, self.num_envs), self._state, jnp.asarray(actions, jnp.int32), self.params
        )
        return (
            np.asarray(obs, np.float32),
            np.asarray(reward, np.float64),
            np.asarray(terminated),
            np.asarray(truncated),
            _info_to_numpy(info),
        )


def _register() -> None:
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(
            id=ENV_ID,
            entry_point=f"{__name__}:TrackingGymEnv",
            vector_entry_point=f"{__name__}:TrackingVectorEnv",
            disable_env_checker=True,
        )


_register()
