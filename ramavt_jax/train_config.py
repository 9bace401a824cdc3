"""Training configuration: `TrainConfig` (frozen, validated) and the named presets 'quick', 'paper', 'smoke'."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ramavt_jax import env as env_lib
from ramavt_jax.augment import AugmentConfig
from ramavt_jax.network import NetworkConfig
from ramavt_jax.render import CameraConfig


def _fail(msg: str):
    raise ValueError(f"TrainConfig: {msg}")


def _integer(config, name: str, lo: int | None = None) -> None:
    v = getattr(config, name)
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        _fail(f"{name} must be an int, got {v!r}")
    if lo is not None and v < lo:
        _fail(f"{name} must be >= {lo}, got {v}")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything a training run needs. Frozen; validated on construction. Sizes in env steps are totals over envs.

    Derived values are properties (nothing is written back): ``sequence_length``, ``env_steps_per_iteration``,
    ``updates_per_iteration``, ``env_steps_per_chunk``, ``num_chunks``.
    """

    env: env_lib.EnvConfig = env_lib.EnvConfig(camera=CameraConfig(resolution=64), autoreset="next_step")
    env_params: tuple = ()  # ((name, value), ...) overrides of EnvParams for TRAINING (evaluation uses eval_params)
    network: NetworkConfig = NetworkConfig()
    # ---- acting

    num_envs: int = 64  # parallel envs (they all act every step)
    rollout_steps: int = 20  # env steps per env per iteration
    iterations_per_chunk: int = 25  # iterations per jitted chunk (the host logs and checkpoints between chunks)
    total_env_steps: int = 1_280_000  # training length, env steps over all envs (a multiple of a chunk's)
    eps_start: float = 0.9  # epsilon-greedy from eps_start to eps_end (the original schedule: 0.9 -> 0.1)
    eps_end: float = 0.1  # final exploration rate
    eps_decay_steps: int = 800_000  # linear over this many env steps (all envs together)
    # ---- replay

    replay_capacity: int = 64_000  # env steps kept (all envs); divisible by num_envs
    burn_in: int = 10  # window steps run from the stored recurrent state without gradient before the trained ones
    train_len: int = 20  # trained transitions per sampled window (window = burn_in + train_len + 1 observations)
    sample_period: int = 1  # stride between admissible window starts
    batch_size: int = 32  # windows per gradient step
    learning_starts: int = 20_000  # env steps stored before the first update
    obs_dtype: str = "uint8"  # replay storage of observations
    replay_ratio: float = 1.0  # trained frames (batch_size * train_len) per env frame
    # ---- learner

    lr: float = 5e-4  # Adam learning rate
    adam_eps: float = 1e-4  # Adam epsilon
    max_grad_norm: float = 10.0  # 0 = no clipping
    gamma: float = 0.97  # discount
    n_step: int = 5  # n-step TD targets (<= train_len)
    double_q: bool = True  # double-Q targets: the online net picks the action, the target net values it
    value_rescale: bool = False  # R2D2's invertible value rescaling of the targets
    huber_delta: float | None = None  # None = mean squared TD error (the original loss), else the Huber threshold
    reward_scale: float = 0.1  # rewards are multiplied by this in the TD targets
    target_update: str = "polyak"  # 'polyak' | 'period'
    polyak_tau: float = 0.01  # target net moves this fraction towards the online net per step ('polyak')
    target_period: int = 500  # gradient steps between hard target syncs ('period')
    # Bootstrap through 'target lost' terminations as through time limits. The env ends an episode once the target
    # has been lost for lost_patience steps; with a terminal value of 0 a tracker whose per-step reward is negative
    # (in view but a few metres off: 1 - w * distance < 0) gains by losing the target on purpose. Bootstrapping from
    # the lost final observation values it as if the episode went on, which removes that incentive. The env's
    # reward and episode rules (and therefore evaluation) are unchanged.
    bootstrap_lost: bool = False
    augment: bool = False  # augment the sampled windows' images (augment_config)
    # augment.AugmentConfig; None = cutout only. Crops, flips and rotations move the target in the image, and the
    # target's image position and size are the state here: they would change the correct action.
    augment_config: Any = None
    # ---- host driver

    eval_episodes: int = 32  # per split at the end (0 = no final evaluation)
    eval_max_steps: int = 1000  # episode cap of the final evaluation
    checkpoint_every_chunks: int = 10  # 0 = only at the end / on interrupt
    checkpoint_replay: bool = True  # store the replay buffer too: resume is bit-exact
    keep_checkpoints: int = 2  # the newest checkpoints kept (older ones are deleted)
    tensorboard: bool = False  # also log to out/tb (needs tensorboardX)
    debug_nan_at_update: int = -1  # tests: the loss becomes NaN from this gradient step on (-1 = off)

    def __post_init__(self):
        if isinstance(self.env_params, dict):
            object.__setattr__(self, "env_params", tuple(sorted(self.env_params.items())))
        self._check_parts()
        self._check_values()
        self._check_sizes()

    def _check_parts(self) -> None:
        """The nested configs and overrides: types, and what the trainer supports."""
        if not isinstance(self.env, env_lib.EnvConfig):
            _fail(f"env must be an env.EnvConfig, got {type(self.env).__name__}")
        if self.env.autoreset != "next_step":
            _fail("env.autoreset must be 'next_step' for training (the final observation of every episode is stored "
                  f"and truncation bootstraps from it), got {self.env.autoreset!r}")
        if not isinstance(self.network, NetworkConfig):
            _fail(f"network must be a network.NetworkConfig, got {type(self.network).__name__}")
        if self.network.num_actions != env_lib.NUM_ACTIONS:
            _fail(f"network.num_actions={self.network.num_actions} but the env has {env_lib.NUM_ACTIONS} actions")
        if self.network.norm == "batch":
            _fail("network.norm='batch' is not supported by the trainer (acting and learning must see the same "
                  "network); use 'layer' or 'none'")
        known = {f.name for f in dataclasses.fields(env_lib.EnvParams)} - {"catalogue"}
        for item in self.env_params:
            if not (isinstance(item, tuple) and len(item) == 2 and item[0] in known):
                _fail(f"env_params must be (name, value) pairs naming EnvParams fields {sorted(known)}, got {item!r}")
        if self.augment and self.augment_config is not None and not isinstance(self.augment_config, AugmentConfig):
            _fail(f"augment_config must be an augment.AugmentConfig, got {type(self.augment_config).__name__}")

    def _check_values(self) -> None:
        """Each number on its own: types and ranges."""
        for name in ("num_envs", "rollout_steps", "iterations_per_chunk", "total_env_steps", "replay_capacity",
                     "train_len", "sample_period", "batch_size", "n_step", "target_period", "eval_max_steps",
                     "keep_checkpoints"):
            _integer(self, name, 1)
        for name in ("eps_decay_steps", "burn_in", "learning_starts", "eval_episodes", "checkpoint_every_chunks"):
            _integer(self, name, 0)
        _integer(self, "debug_nan_at_update", -1)
        for name in ("eps_start", "eps_end", "gamma"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                _fail(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if not self.lr > 0 or not self.adam_eps > 0:
            _fail(f"lr and adam_eps must be > 0, got lr={self.lr}, adam_eps={self.adam_eps}")
        if not self.max_grad_norm >= 0:
            _fail(f"max_grad_norm must be >= 0 (0 = no clipping), got {self.max_grad_norm}")
        if not self.reward_scale > 0:
            _fail(f"reward_scale must be > 0, got {self.reward_scale}")
        if self.huber_delta is not None and not self.huber_delta > 0:
            _fail(f"huber_delta must be None (MSE) or > 0, got {self.huber_delta}")
        if self.target_update not in ("polyak", "period"):
            _fail(f"target_update must be 'polyak' or 'period', got {self.target_update!r}")
        if not 0.0 < self.polyak_tau <= 1.0:
            _fail(f"polyak_tau must be in (0, 1], got {self.polyak_tau}")
        if self.obs_dtype not in ("uint8", "float16", "float32"):
            _fail(f"obs_dtype must be 'uint8', 'float16' or 'float32', got {self.obs_dtype!r}")
        if not self.replay_ratio > 0:
            _fail(f"replay_ratio must be > 0, got {self.replay_ratio}")

    def _check_sizes(self) -> None:
        """How the sizes fit together: chunks, replay rows, windows, gradient steps per iteration."""
        if self.n_step > self.train_len:
            _fail(f"n_step={self.n_step} must be <= train_len={self.train_len}")
        n = self.env_steps_per_chunk
        if self.total_env_steps % n:
            _fail(f"total_env_steps={self.total_env_steps} must be a multiple of the env steps per chunk "
                  f"(num_envs * rollout_steps * iterations_per_chunk = {n}); try "
                  f"{max(1, round(self.total_env_steps / n)) * n}")
        if self.replay_capacity % self.num_envs:
            _fail(f"replay_capacity={self.replay_capacity} must be divisible by num_envs={self.num_envs}")
        per_env = self.replay_capacity // self.num_envs
        if per_env < max(self.sequence_length, self.rollout_steps):
            _fail(f"replay_capacity={self.replay_capacity} leaves {per_env} steps per env, fewer than the window "
                  f"(burn_in + train_len + 1 = {self.sequence_length}) or rollout_steps ({self.rollout_steps})")
        if self.sample_period > self.sequence_length:
            _fail(f"sample_period={self.sample_period} must be <= the window length {self.sequence_length}")
        if self.learning_starts > self.replay_capacity:
            _fail(f"learning_starts={self.learning_starts} exceeds replay_capacity={self.replay_capacity}")
        if self.learning_starts > self.total_env_steps:
            _fail(f"learning_starts={self.learning_starts} exceeds total_env_steps={self.total_env_steps}: nothing "
                  f"would be learned")
        exact = self.replay_ratio * self.env_steps_per_iteration / (self.batch_size * self.train_len)
        if exact < 1 - 1e-9 or abs(exact - round(exact)) > 1e-6:
            _fail(f"replay_ratio={self.replay_ratio} gives {exact:.4g} gradient steps per iteration (replay_ratio * "
                  f"num_envs * rollout_steps / (batch_size * train_len)); it must be a whole number >= 1")
        if not self.network.recurrent and self.burn_in < self.network.frame_stack - 1:
            _fail(f"variant 'drlavt' rebuilds its {self.network.frame_stack}-frame stack from the window's own "
                  f"observations during burn-in: burn_in must be >= frame_stack - 1 = {self.network.frame_stack - 1}, "
                  f"got {self.burn_in}")

    # ---- derived (read-only)
    @property
    def sequence_length(self) -> int:
        return self.burn_in + self.train_len + 1

    @property
    def env_steps_per_iteration(self) -> int:
        return self.num_envs * self.rollout_steps

    @property
    def updates_per_iteration(self) -> int:
        return int(round(self.replay_ratio * self.env_steps_per_iteration / (self.batch_size * self.train_len)))

    @property
    def env_steps_per_chunk(self) -> int:
        return self.env_steps_per_iteration * self.iterations_per_chunk

    @property
    def num_chunks(self) -> int:
        return self.total_env_steps // self.env_steps_per_chunk

    def to_dict(self) -> dict:
        """JSON-friendly nested dict (for config.json and checkpoint metadata)."""
        def conv(x):
            if dataclasses.is_dataclass(x):
                return {f.name: conv(getattr(x, f.name)) for f in dataclasses.fields(x)}
            if isinstance(x, (tuple, list)):
                return [conv(v) for v in x]
            if isinstance(x, (np.integer, np.floating)):
                return x.item()
            return x
        return conv(self)


def _quick() -> TrainConfig:
    """The README main job (the earlier, cheaper-encoder version took 5.6 min on 2 CPU cores): the task at 32x32 depth with a small RAMAVT
    (stride-2 first conv, 16-32-32 channels, a 4x4 final map = 16 attention tokens, dense/LSTM 128) whose encoder
    sees absolute depth and image position (hit-mask and coordinate channels, pre-norm pooled skip), trained with
    'target lost' bootstrapped (no incentive to lose the target), replay ratio 2. RESULTS.md has the measurements."""
    return TrainConfig(
        env=env_lib.EnvConfig(camera=CameraConfig(resolution=32), autoreset="next_step"),
        network=NetworkConfig(variant="ramavt", channels=(16, 32, 32), kernels=(3, 3, 3), strides=(2, 1, 1),
                              pools=(True, True, False), se_reduction=4, attention_heads=4, dense=128, lstm=128,
                              lstm_layers=1, head=128, coord_channels=True, pooled_skip=True),
        num_envs=64, rollout_steps=20, iterations_per_chunk=25, total_env_steps=384_000,
        eps_start=1.0, eps_end=0.05, eps_decay_steps=200_000,
        replay_capacity=64_000, burn_in=10, train_len=20, batch_size=32, learning_starts=10_240,
        replay_ratio=2.0, lr=5e-4, gamma=0.97, n_step=5, reward_scale=0.1, target_update="polyak", polyak_tau=0.01,
        bootstrap_lost=True, eval_episodes=32, checkpoint_every_chunks=5,
    )


def _long() -> TrainConfig:
    """The quick preset with 3x the env steps (1.15M), exploration decaying over 400k steps and a 128k-step replay:
    3x the quick preset's compute. The shipped pretrained agent was trained with it."""
    return dataclasses.replace(_quick(), total_env_steps=1_152_000, eps_decay_steps=400_000, replay_capacity=128_000,
                               checkpoint_every_chunks=6)


def _paper() -> TrainConfig:
    """The paper's settings: 256x256 depth, full RAMAVT, batch 64, Adam 1e-4, gamma 0.99, 50,000-step replay, plain
    1-step DRQN targets with a hard-synced target net, MSE, epsilon 0.9 -> 0.1, *orig* windows of 4 burn-in + 8
    trained steps. Needs hours on a CPU; meant for a GPU machine."""
    return TrainConfig(
        env=env_lib.EnvConfig(camera=CameraConfig(resolution=256), autoreset="next_step"),
        network=NetworkConfig(variant="ramavt"),
        num_envs=16, rollout_steps=20, iterations_per_chunk=10, total_env_steps=2_000_000,
        eps_start=0.9, eps_end=0.1, eps_decay_steps=1_000_000,
        replay_capacity=50_000, burn_in=4, train_len=8, batch_size=64, learning_starts=10_000,
        replay_ratio=1.6, lr=1e-4, gamma=0.99, n_step=1, double_q=False, reward_scale=1.0, target_update="period",
        target_period=1000, checkpoint_every_chunks=20, eval_episodes=32,
    )


def _smoke() -> TrainConfig:
    """Seconds of compute: plumbing checks (tests, CI). 16x16 depth, a tiny plain DRQN, 4 chunks of 320 steps."""
    return TrainConfig(
        env=env_lib.EnvConfig(camera=CameraConfig(resolution=16), autoreset="next_step"),
        network=NetworkConfig(variant="origin", channels=(8, 8), kernels=(3, 3), strides=(1, 1), pools=(True, True),
                              dense=32, lstm=32, lstm_layers=1, head=32),
        num_envs=8, rollout_steps=10, iterations_per_chunk=4, total_env_steps=1280, eps_decay_steps=1280,
        replay_capacity=800, burn_in=3, train_len=5, batch_size=4, learning_starts=160, replay_ratio=0.5, n_step=2,
        eval_episodes=4, eval_max_steps=50, checkpoint_every_chunks=2,
    )


PRESETS = {"quick": _quick, "long": _long, "paper": _paper, "smoke": _smoke}


def preset(name: str, **overrides: Any) -> TrainConfig:
    """A named configuration ('quick' | 'paper' | 'smoke'); keyword overrides replace top-level fields."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
    cfg = PRESETS[name]()
    return dataclasses.replace(cfg, **overrides) if overrides else cfg
