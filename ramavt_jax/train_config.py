"""Training configuration: one frozen, validated config per concern (``acting``, ``replay``, ``learner``, ``run``,
beside the env's and the network's own), composed into `TrainConfig`; the named presets are in
:mod:`ramavt_jax.presets`.

Each group checks its own values when it is built; `TrainConfig` checks once, at construction, how the groups fit
together (window vs replay rows, whole gradient steps per iteration, ...). ``TrainConfig.to_dict`` is the
config.json form and ``TrainConfig.from_dict`` reads it back (:mod:`ramavt_jax.config_dicts`, which also drops the
retired fields of earlier versions).
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

import numpy as np

from ramavt_jax import env as env_lib
from ramavt_jax.augment import AugmentConfig
from ramavt_jax.config_dicts import build, without_retired_fields
from ramavt_jax.env_config import check_settings
from ramavt_jax.imitation import BLIND_LABELS
from ramavt_jax.losses import TDConfig
from ramavt_jax.network import NetworkConfig
from ramavt_jax.render import CameraConfig
from ramavt_jax.replay_config import ReplayConfig
from ramavt_jax.value_checks import check_finite, check_floats, check_ints

__all__ = ["ActingConfig", "ReplayConfig", "LearnerConfig", "RunConfig", "TrainConfig"]


@dataclasses.dataclass(frozen=True)
class ActingConfig:
    """The acting envs and their epsilon-greedy exploration."""

    num_envs: int = 64  # parallel envs (they all act every step)
    rollout_steps: int = 20  # env steps per env per iteration
    eps_start: float = 0.9  # epsilon-greedy from eps_start to eps_end (the original schedule: 0.9 -> 0.1)
    eps_end: float = 0.1  # final exploration rate
    eps_decay_steps: int = 800_000  # linear over this many env steps (all envs together)

    def __post_init__(self):
        check_ints("ActingConfig", self, dict(num_envs=1, rollout_steps=1, eps_decay_steps=0))
        check_floats("ActingConfig", self)
        for name in ("eps_start", "eps_end"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"ActingConfig: {name} must be in [0, 1], got {getattr(self, name)}")


@dataclasses.dataclass(frozen=True)
class LearnerConfig:
    """When and how much the learner trains, the optimiser, the loss terms' settings and the sampled windows'
    augmentation."""

    learning_starts: int = 20_000  # env steps (all envs) before the first update
    replay_ratio: float = 1.0  # trained frames (batch_size * train_len) per env frame
    lr: float = 5e-4  # Adam learning rate (constant; Adam's epsilon is train.ADAM_EPS)
    max_grad_norm: float = 10.0  # 0 = no clipping
    gamma: float = 0.97  # discount
    n_step: int = 5  # n-step TD targets (<= train_len; 1 = the paper's one-step DRQN targets)
    double_q: bool = True  # double-Q targets: the online net picks the action, the target net values it (a no-op
    # with bootstrap_from='online': one net picks and values, which is the plain max)
    # Auxiliary loss weight (0 = off; losses.aux_term): the aux head (NetworkConfig.aux_outputs = 3) predicts the
    # true tracking error (camera frame, in stand-off distances) at each trained obs: simulator state, stored in the
    # replay (imitation.true_tracking_state). With aux_outputs = 6 it also predicts the target's velocity relative to
    # the chaser (stand-off distances per s).
    aux_weight: float = 0.0
    reward_scale: float = 0.1  # rewards are multiplied by this in the TD targets
    # DQfD's large-margin loss (imitation.margin_term) towards the true-state one-step look-ahead's action at every
    # trained step, the agent's own included, weighted by this (0 = off: no labels computed or stored).
    expert_margin_weight: float = 0.0
    # The label at the steps before the target is first in view (imitation.unseen_yet), whose blank images cannot
    # show where the look-ahead's action points: 'teacher' (that action, as at every other step), 'none' (no label:
    # the TD loss alone decides how to search) or 'retreat' (back along the camera axis, env.RETREAT, which
    # brings a target at any bearing towards the view).
    blind_label: str = "teacher"
    target_update: str = "polyak"  # 'polyak' | 'period'
    # 'target' (net, over the whole window) | 'online': the targets bootstrap from the online net's own trained pass
    # under stop_gradient (no target pass); the target net is still averaged, for RunConfig.policy_params='target'.
    bootstrap_from: str = "target"
    polyak_tau: float = 0.01  # target net moves this fraction towards the online net per step ('polyak')
    target_period: int = 500  # gradient steps between hard target syncs ('period')
    # Bootstrap through 'target lost' terminations as through time limits: with a terminal value of 0, a tracker
    # whose per-step reward is negative (1 - w * distance < 0) gains by losing the target on purpose; bootstrapping
    # removes that incentive. The env's reward and episode rules (and so evaluation) are unchanged.
    bootstrap_lost: bool = False
    augment: bool = False  # augment the sampled windows' images with augment_config (Table III's augmentation row)
    # Cutout only by default: crops, flips and rotations move the target in the image, and the target's image
    # position and size are the state here, so they would change the correct action.
    augment_config: AugmentConfig = AugmentConfig(crop=False, flip=False, rot90=False)

    def __post_init__(self):
        check_ints("LearnerConfig", self, dict(learning_starts=0, n_step=1, target_period=1))
        check_floats("LearnerConfig", self)
        fail = lambda msg: ValueError(f"LearnerConfig: {msg}")  # noqa: E731
        for name, ok, rule in (
            ("lr", self.lr > 0, "> 0"),
            ("gamma", 0.0 <= self.gamma <= 1.0, "in [0, 1]"),
            ("polyak_tau", 0.0 < self.polyak_tau <= 1.0, "in (0, 1]"),
            ("max_grad_norm", self.max_grad_norm >= 0, ">= 0 (0 = no clipping)"),
            ("aux_weight", self.aux_weight >= 0, ">= 0 (0 = no auxiliary loss)"),
            ("reward_scale", self.reward_scale > 0, "> 0"),
            ("expert_margin_weight", self.expert_margin_weight >= 0, ">= 0 (0 = no margin loss)"),
            ("blind_label", self.blind_label in BLIND_LABELS, f"one of {BLIND_LABELS}"),
            ("replay_ratio", self.replay_ratio > 0, "> 0"),
            ("target_update", self.target_update in ("polyak", "period"), "'polyak' or 'period'"),
            ("bootstrap_from", self.bootstrap_from in ("target", "online"), "'target' or 'online'"),
        ):
            if not ok:
                raise fail(f"{name} must be {rule}, got {getattr(self, name)!r}")
        if not isinstance(self.augment_config, AugmentConfig):
            raise fail(f"augment_config must be an augment.AugmentConfig, got {type(self.augment_config).__name__}")

    @property
    def td(self) -> TDConfig:
        """The TD loss's view of these settings (losses.TDConfig)."""
        return TDConfig(gamma=self.gamma, n_step=self.n_step, double_q=self.double_q)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """The run's length and what the host does between chunks: logs, checkpoints, the final evaluation."""

    total_env_steps: int = 1_280_000  # training length, env steps over all envs (a multiple of a chunk's)
    iterations_per_chunk: int = 25  # iterations per jitted chunk (the host logs and checkpoints between chunks)
    eval_episodes: int = 32  # per split at the end (0 = no final evaluation)
    eval_max_steps: int = 1000  # episode cap of the final evaluation
    checkpoint_every_chunks: int = 10  # 0 = only at the end / on interrupt
    checkpoint_replay: bool = True  # store the replay buffer too: resume is bit-exact
    keep_checkpoints: int = 2  # the newest checkpoints kept (older ones are deleted)
    tensorboard: bool = False  # also log to out/tb (needs tensorboardX)
    # The parameters the trained greedy policy acts with (final evaluation, `--policy checkpoint`, export): 'online'
    # (the last gradient step's), 'target' (the target net's; with Polyak updates an average over ~1/tau updates)
    # or 'averaged' (the target net's averaged over the chunks after policy_average_from). Training acts with the
    # online net whatever this says, so it changes no training step.
    policy_params: typing.Literal["online", "target", "averaged"] = "online"
    # Polyak-Ruppert tail averaging: the uniform mean of the target params at the ends of chunks S+1, S+2, ... is
    # kept beside them (LearnerState.averaged_params; equal to the target params up to chunk S; None = not kept).
    # Counted from the run's start, so a run extended on resume keeps averaging and one that ends by chunk S has
    # averaged nothing.
    policy_average_from: int | None = None
    # The divergence guard: training stops (the diverged state unsaved; exit status 2 from `ramavt train`) after a
    # chunk whose mean loss is above this bound, or whose loss, mean Q or gradient norm is not a finite number.
    # None: only the non-finite figures stop it.
    max_loss: float | None = 1e10

    def __post_init__(self):
        check_floats("RunConfig", self)
        if self.max_loss is not None and not self.max_loss > 0:
            raise ValueError(f"RunConfig: max_loss must be > 0 (None: no bound on the loss), got {self.max_loss}")
        check_ints(
            "RunConfig",
            self,
            dict(
                total_env_steps=1,
                iterations_per_chunk=1,
                eval_episodes=0,
                eval_max_steps=1,
                checkpoint_every_chunks=0,
                keep_checkpoints=1,
            ),
        )
        if self.policy_average_from is not None:
            check_ints("RunConfig", self, dict(policy_average_from=0))
        if self.policy_params not in ("online", "target", "averaged"):
            raise ValueError(
                f"RunConfig: policy_params must be 'online', 'target' or 'averaged', got {self.policy_params!r}"
            )
        if self.policy_params == "averaged" and self.policy_average_from is None:
            raise ValueError(
                "RunConfig: policy_params='averaged' needs policy_average_from (the chunk after which "
                "the target params are averaged), or policy_params='target'"
            )


_GROUPS = {"acting": ActingConfig, "replay": ReplayConfig, "learner": LearnerConfig, "run": RunConfig}
# {name: (group, field)}: every group field by its own name (the names are unique across the groups), so that
# TrainConfig.override(lr=1e-3) needs no group prefix.
_FIELD_GROUPS = {f.name: (g, f.name) for g, cls in _GROUPS.items() for f in dataclasses.fields(cls)}


def _fail(msg: str):
    raise ValueError(f"TrainConfig: {msg}")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything a training run needs: the groups, composed. Frozen; validated once on construction (each group
    checks its own values; this class how they fit together). Sizes in env steps are totals over envs.

    Derived values are properties (nothing is written back): ``sequence_length``, ``env_steps_per_iteration``,
    ``updates_per_iteration``, ``env_steps_per_chunk``, ``num_chunks``. ``override(lr=1e-3, ...)`` replaces group
    fields by their own names.
    """

    env: env_lib.EnvConfig = env_lib.EnvConfig(camera=CameraConfig(resolution=64), autoreset="next_step")
    env_params: tuple = ()  # ((name, value), ...) overrides of EnvParams for TRAINING (evaluation uses eval_params)
    network: NetworkConfig = NetworkConfig()
    acting: ActingConfig = ActingConfig()
    replay: ReplayConfig = ReplayConfig()
    learner: LearnerConfig = LearnerConfig()
    run: RunConfig = RunConfig()

    def __post_init__(self):
        if isinstance(self.env_params, dict):
            object.__setattr__(self, "env_params", tuple(sorted(self.env_params.items())))
        self._check_parts()
        self._check_sizes()

    def _check_parts(self) -> None:
        """The groups' types, and what the trainer supports of the env and network configs."""
        for name, cls in dict(env=env_lib.EnvConfig, network=NetworkConfig, **_GROUPS).items():
            if not isinstance(getattr(self, name), cls):
                _fail(f"{name} must be a {cls.__name__}, got {type(getattr(self, name)).__name__}")
        if self.env.autoreset != "next_step":
            _fail(
                "env.autoreset must be 'next_step' for training (the final observation of every episode is stored "
                f"and truncation bootstraps from it), got {self.env.autoreset!r}"
            )
        if self.network.num_actions != env_lib.NUM_ACTIONS:
            _fail(f"network.num_actions={self.network.num_actions} but the env has {env_lib.NUM_ACTIONS} actions")
        if (self.learner.aux_weight > 0) != (self.network.aux_outputs > 0):  # error x, y, z (+ velocity)
            _fail(
                f"learner.aux_weight > 0 and network.aux_outputs = 3 or 6 go together (the head and its loss), got "
                f"{self.learner.aux_weight} and {self.network.aux_outputs}"
            )
        if self.network.norm == "batch":
            _fail(
                "network.norm='batch' is not supported by the trainer (acting and learning must see the same "
                "network); use 'layer' or 'none'"
            )
        known = {f.name for f in dataclasses.fields(env_lib.EnvParams)} - {"catalogue"}
        for item in self.env_params:
            if not (isinstance(item, tuple) and len(item) == 2 and item[0] in known):
                _fail(f"env_params must be (name, value) pairs naming EnvParams fields {sorted(known)}, got {item!r}")
            try:
                check_finite(f"env_params: {item[0]}", item[1])
            except ValueError as e:
                _fail(str(e))
        try:  # each in its range (env_config.RANGES), before anything compiles
            check_settings(dict(self.env_params), self.env, owner="env_params: ")
        except ValueError as e:
            _fail(str(e))

    def _check_sizes(self) -> None:
        """How the groups' sizes fit together: chunks, replay rows, windows, gradient steps per iteration."""
        a, r, lr, run = self.acting, self.replay, self.learner, self.run
        if lr.n_step > r.train_len:
            _fail(f"learner.n_step={lr.n_step} must be <= replay.train_len={r.train_len}")
        n = self.env_steps_per_chunk
        if run.total_env_steps % n:
            _fail(
                f"run.total_env_steps={run.total_env_steps} must be a multiple of the env steps per chunk "
                f"(acting.num_envs * acting.rollout_steps * run.iterations_per_chunk = {n}); try "
                f"{max(1, round(run.total_env_steps / n)) * n}"
            )
        if r.capacity_steps % a.num_envs:
            _fail(f"replay.capacity_steps={r.capacity_steps} must be divisible by acting.num_envs={a.num_envs}")
        per_env = r.capacity_steps // a.num_envs
        if per_env < max(r.sequence_length, a.rollout_steps):
            _fail(
                f"replay.capacity_steps={r.capacity_steps} leaves {per_env} steps per env, fewer than the window "
                f"(burn_in + train_len + 1 = {r.sequence_length}) or acting.rollout_steps ({a.rollout_steps})"
            )
        if lr.learning_starts > r.capacity_steps:
            _fail(f"learner.learning_starts={lr.learning_starts} exceeds replay.capacity_steps={r.capacity_steps}")
        if lr.learning_starts > run.total_env_steps:
            _fail(
                f"learner.learning_starts={lr.learning_starts} exceeds run.total_env_steps={run.total_env_steps}: "
                f"nothing would be learned"
            )
        exact = lr.replay_ratio * self.env_steps_per_iteration / (r.batch_size * r.train_len)
        if exact < 1 - 1e-9 or abs(exact - round(exact)) > 1e-6:
            _fail(
                f"learner.replay_ratio={lr.replay_ratio} gives {exact:.4g} gradient steps per iteration "
                f"(replay_ratio * num_envs * rollout_steps / (batch_size * train_len)); must be a whole number >= 1"
            )
        if not self.network.recurrent and r.burn_in < self.network.frame_stack - 1:
            _fail(
                f"variant 'drlavt' rebuilds its {self.network.frame_stack}-frame stack from the window's own obs "
                f"during burn-in: replay.burn_in must be >= frame_stack - 1 = {self.network.frame_stack - 1}"
            )

    # ---- derived (read-only)
    @property
    def sequence_length(self) -> int:
        return self.replay.sequence_length

    @property
    def env_steps_per_iteration(self) -> int:
        return self.acting.num_envs * self.acting.rollout_steps

    @property
    def updates_per_iteration(self) -> int:
        per_update = self.replay.batch_size * self.replay.train_len
        return int(round(self.learner.replay_ratio * self.env_steps_per_iteration / per_update))

    @property
    def total_updates(self) -> int:
        """Gradient steps in the whole run: every iteration from the one that reaches learning_starts on."""
        per_it = self.env_steps_per_iteration
        waiting = max(-(-self.learner.learning_starts // per_it) - 1, 0)
        return max(self.run.total_env_steps // per_it - waiting, 0) * self.updates_per_iteration

    @property
    def env_steps_per_chunk(self) -> int:
        return self.env_steps_per_iteration * self.run.iterations_per_chunk

    @property
    def num_chunks(self) -> int:
        return self.run.total_env_steps // self.env_steps_per_chunk

    # ---- changing and serialising
    def override(self, **fields: Any) -> TrainConfig:
        """A copy with fields replaced: this class's own (``env=``, ``learner=``, ...) and any group's field by its
        own name (``lr=1e-3`` is ``learner.lr``; see _FIELD_GROUPS). Validated once, as a whole."""
        top = {k: v for k, v in fields.items() if k in _TOP_FIELDS}
        groups: dict[str, dict] = {}
        for key, value in fields.items():
            if key not in _TOP_FIELDS:
                if key not in _FIELD_GROUPS:
                    _fail(f"unknown field {key!r}: fields are {sorted(_TOP_FIELDS)} or a group's field by name")
                group, name = _FIELD_GROUPS[key]
                groups.setdefault(group, {})[name] = value
        for group, changes in groups.items():
            top[group] = dataclasses.replace(top.get(group, getattr(self, group)), **changes)
        return dataclasses.replace(self, **top)

    def to_dict(self) -> dict:
        """JSON-friendly nested dict (for config.json and checkpoint metadata)."""

        def conv(x):
            if dataclasses.is_dataclass(x):
                return {f.name: conv(getattr(x, f.name)) for f in dataclasses.fields(x)}
            if isinstance(x, (tuple, list)):
                return [conv(v) for v in x]
            return x.item() if isinstance(x, (np.integer, np.floating)) else x

        return conv(self)

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        """The config of a ``to_dict()`` dict (config.json's "config"): lists become tuples, fields it lacks take
        their defaults, retired fields are dropped or refused (without_retired_fields), other unknown keys are
        ignored."""
        return build(cls, without_retired_fields(data))


_TOP_FIELDS = {f.name for f in dataclasses.fields(TrainConfig)}
