"""Sequence replay settings (`ReplayConfig`): storage, windows and prioritised sampling; validated when built."""

from __future__ import annotations

import dataclasses

import numpy as np

OBS_DTYPES = ("uint8", "float16", "float32")  # storage dtypes of observations
STATE_DTYPES = ("float32", "bfloat16", "float16")  # storage dtypes of the recurrent state


@dataclasses.dataclass(frozen=True)
class ReplayConfig:
    """Sequence replay settings.  Sizes are in env steps, summed over all envs.

    Attributes:
      capacity_steps: env steps kept (total over envs; must be divisible by ``num_envs``).  This is the memory
        budget, *not* the total number of training timesteps.
      burn_in: leading steps of each window that only warm up the recurrent state (no loss; fixes
        :attr:`SequenceBatch.loss_mask`).
      train_len: trained transitions per window, after the burn-in.  A window has :attr:`sequence_length` =
        ``burn_in + train_len + 1`` steps (the last one only gives the bootstrap observation).
      period: stride between admissible window starts (1 = any start; ``sequence_length - 1`` = windows share
        only their end points).  The grid is anchored at the oldest stored step.
      batch_size: windows per sample.
      obs_dtype: storage dtype of observations: ``'uint8'`` (float [0, 1] quantised to 1/255, error <= 1/510),
        ``'float16'`` or ``'float32'``.  Samples are always float32.
      state_dtype: storage dtype of the recurrent state (``'float32'``, ``'bfloat16'``, ``'float16'``); samples
        are cast back to the example's dtype.
      min_fill_steps: env steps (total over envs) stored before :meth:`SequenceReplay.can_sample` is true; at
        least ``sequence_length`` per env is always required.
      priority_exponent: 0 samples windows uniformly (the default). Above 0, prioritised sequence replay (as R2D2,
        which uses 0.9): a window is drawn with probability proportional to its priority to this power (flashbax's
        prioritised trajectory buffer), where the learner sets a window's priority from its TD errors
        (``priority_max_share`` max + the rest mean of their magnitudes). A new window enters at flashbax's
        max(1, whole part of the largest powered priority so far): flashbax 0.1.3 rounds it down, so with TD errors
        below 1 new windows enter at 1, above the windows already trained on, and are drawn more often until
        trained on.
      importance_exponent: beta of the importance weights ``(P_i) ** -beta / max_j (P_j) ** -beta`` over the batch
        that correct the loss for prioritised sampling (R2D2: 0.6); unused when sampling is uniform.
      priority_max_share: eta of a window's priority ``eta max |td| + (1 - eta) mean |td|`` (R2D2: 0.9).
    """

    capacity_steps: int = 64_000
    burn_in: int = 10
    train_len: int = 20
    period: int = 1
    batch_size: int = 32
    obs_dtype: str = "uint8"
    state_dtype: str = "float32"
    min_fill_steps: int = 0
    priority_exponent: float = 0.0
    importance_exponent: float = 0.6
    priority_max_share: float = 0.9

    def __post_init__(self):
        for name in ("priority_exponent", "importance_exponent", "priority_max_share"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not 0 <= value <= 1:
                raise ValueError(f"ReplayConfig.{name} must be a number in [0, 1], got {value!r}")
        for name in ("capacity_steps", "burn_in", "train_len", "period", "batch_size", "min_fill_steps"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
                raise ValueError(f"ReplayConfig.{name} must be an int, got {value!r}")
        for name, lo in (("capacity_steps", 1), ("burn_in", 0), ("train_len", 1), ("batch_size", 1)):
            if getattr(self, name) < lo:
                raise ValueError(f"ReplayConfig.{name} must be >= {lo}, got {getattr(self, name)}")
        if not 1 <= self.period <= self.sequence_length:
            raise ValueError(
                f"ReplayConfig.period must be in [1, sequence_length={self.sequence_length}] (a larger stride "
                f"leaves steps that are never sampled), got {self.period}"
            )
        if self.obs_dtype not in OBS_DTYPES:
            raise ValueError(f"ReplayConfig.obs_dtype must be one of {sorted(OBS_DTYPES)}, got {self.obs_dtype!r}")
        if self.state_dtype not in STATE_DTYPES:
            raise ValueError(
                f"ReplayConfig.state_dtype must be one of {sorted(STATE_DTYPES)}, got {self.state_dtype!r}"
            )
        if not 0 <= self.min_fill_steps <= self.capacity_steps:
            raise ValueError(
                f"ReplayConfig.min_fill_steps must be in [0, capacity_steps={self.capacity_steps}], "
                f"got {self.min_fill_steps}"
            )

    @property
    def prioritised(self) -> bool:
        return self.priority_exponent > 0

    @property
    def sequence_length(self) -> int:
        return self.burn_in + self.train_len + 1

    def steps_per_env(self, num_envs: int) -> int:
        """Length of each env's circular time axis (validates the config against ``num_envs``)."""
        self.validate(num_envs)
        return self.capacity_steps // num_envs

    def validate(self, num_envs: int) -> None:
        """Checks that depend on the number of envs; raises ``ValueError`` with a readable message."""
        if not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
        if self.capacity_steps % num_envs:
            lo = (self.capacity_steps // num_envs) * num_envs
            raise ValueError(
                f"ReplayConfig.capacity_steps={self.capacity_steps} must be divisible by num_envs={num_envs} "
                f"(each env gets its own row of capacity_steps // num_envs steps); try {lo} or {lo + num_envs}"
            )
        per_env = self.capacity_steps // num_envs
        if self.prioritised and per_env % self.period:
            raise ValueError(
                f"ReplayConfig.period={self.period} must divide the {per_env} steps per env of a prioritised buffer "
                f"(flashbax's window grid; capacity_steps={self.capacity_steps}, num_envs={num_envs})"
            )
        if per_env < self.sequence_length:
            raise ValueError(
                f"ReplayConfig.capacity_steps={self.capacity_steps} gives {per_env} steps per env with "
                f"num_envs={num_envs}, fewer than sequence_length={self.sequence_length}; need capacity_steps >= "
                f"{self.sequence_length * num_envs}"
            )
