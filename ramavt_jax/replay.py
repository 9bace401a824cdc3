"""Sequence replay with stored recurrent state (R2D2), a thin wrapper around flashbax's trajectory buffer (uniform
sampling) or its prioritised trajectory buffer (``ReplayConfig.priority_exponent`` > 0).

Storage layout
--------------
The buffer is ``num_envs`` rows of a circular time axis of ``capacity_steps // num_envs`` steps.  Each added
chunk ``[num_envs, T_chunk, ...]`` continues every row in time; sampling returns windows of
``sequence_length`` consecutive steps of one row (one env), never mixing envs and never crossing the write head
(a prioritised buffer's drifted sum tree may draw such a window, at importance weight 0: see SequenceReplay.sample).

Time-step convention (next-step autoreset)
------------------------------------------
The trainer steps the envs with *next-step autoreset*: a step taken from a finished state resets the env instead
of moving it, so every episode's final observation is a real, stored observation.  Stored step t holds

* ``obs``: observation t (quantised for storage, see :class:`ReplayConfig.obs_dtype`);
* ``action``, ``reward``, ``terminated``, ``truncated``: the transition from obs t to obs t+1;
* ``is_first``: obs t is the first observation of an episode.  The network resets its carry there, and the
  transition t-1 -> t (final obs of the previous episode -> reset) is not a real transition and must be masked
  (:func:`loss_mask` does this);
* ``recurrent_state``: the actor's recurrent state *before* consuming obs t (leaves ``[layers, units]``
  per env: the LSTM's h and c, and where the network has it the previous action).  At an
  ``is_first`` step this may be the previous episode's carry; it does not matter because the network resets the
  carry where ``reset`` (= ``is_first``) is set.

So for an episode obs_0 .. obs_K: transitions 0..K-1 are real, transition K-1 has ``terminated`` or
``truncated`` set, step K stores the final obs_K (its action/reward describe the reset and are masked), and the
next step has ``is_first``.  A sampled window of L steps gives the learner L observations and L-1 transitions.

Learner (R2D2): :meth:`SequenceReplay.sample` returns a :class:`SequenceBatch` (the windows' observations and
reset flags, their transitions with the loss mask, and the stored state before each window's first observation in
the network's layout).  The learner runs the first ``burn_in`` steps from that state without gradient and takes
the TD loss over the rest (see ``Trainer.prepare`` in :mod:`ramavt_jax.train`).

Performance: jit ``add`` with the buffer state donated (``donate_argnums``) or keep it in a ``lax.scan`` carry;
otherwise XLA copies the whole buffer on every add (measured ~100x slower on CPU).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import chex
import flashbax as fbx
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ramavt_jax.replay_config import OBS_DTYPES, STATE_DTYPES, ReplayConfig

__all__ = [
    "ReplayConfig",
    "Transition",
    "SequenceBatch",
    "SequenceReplay",
    "make_replay",
    "memory_bytes",
    "loss_mask",
    "sequence_batch",
    "chunk_to_storage",
    "quantise_obs",
    "dequantise_obs",
]

_OBS_DTYPES = {name: jnp.dtype(name) for name in OBS_DTYPES}  # the names ReplayConfig accepts, as dtypes
_STATE_DTYPES = {name: jnp.dtype(name) for name in STATE_DTYPES}


@struct.dataclass
class Transition:
    """One stored time step (shapes per env, without the batch/time prefix).

    In :meth:`SequenceReplay.add` every leaf carries a ``[num_envs, T_chunk]`` prefix; :meth:`SequenceReplay.sample`
    turns ``[batch_size, sequence_length]`` windows of them into a :class:`SequenceBatch`.

    Attributes:
      obs: ``[H, W, C]`` observation t, float in [0, 1] (stored quantised).
      action: ``[]`` int32 action taken at obs t.
      reward: ``[]`` float32 reward of the transition obs t -> obs t+1.
      terminated: ``[]`` bool, obs t+1 is terminal (no bootstrap).
      truncated: ``[]`` bool, the time limit ended the episode at obs t+1 (bootstrap from it).
      is_first: ``[]`` bool, obs t is an episode's first observation (carry reset; transition t-1 masked).
      recurrent_state: the actor's state *before* consuming obs t, any pytree with leaves ``[layers, units]``; the
        trainer stores the network's own ``RecurrentState`` (LSTM ``h``, ``c``, and prev_action where the
        network has them; no frame history).
      privileged: ``[K]`` float32 simulator state at obs t (imitation.true_tracking_state's first K entries, the
        auxiliary loss's label); ``None`` = not stored.
      expert_action: ``[]`` int32 the labeller's action at obs t (imitation.py: the large-margin loss's label);
        ``None`` = not stored.
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    is_first: jax.Array
    recurrent_state: Any
    privileged: jax.Array | None = None
    expert_action: jax.Array | None = None


def quantise_obs(obs: jax.Array, dtype: str) -> jax.Array:
    """Float [0, 1] -> storage dtype.  uint8 rounds to the nearest 1/255; uint8 input is taken as already quantised."""
    target = _OBS_DTYPES[dtype]
    if dtype == "uint8":
        if obs.dtype == jnp.uint8:
            return obs
        return jnp.round(jnp.clip(obs, 0.0, 1.0) * 255.0).astype(jnp.uint8)
    if obs.dtype == jnp.uint8:
        return (obs.astype(jnp.float32) / 255.0).astype(target)
    return obs.astype(target)


def dequantise_obs(obs: jax.Array) -> jax.Array:
    """Storage dtype -> float32 in [0, 1]."""
    if obs.dtype == jnp.uint8:
        return obs.astype(jnp.float32) * (1.0 / 255.0)
    return obs.astype(jnp.float32)


def chunk_to_storage(chunk: Transition) -> Transition:
    """Time-major chunk from an acting ``lax.scan`` -> the batch-major layout :meth:`SequenceReplay.add` takes.

    Input leaves are ``[T_chunk, num_envs, ...]``, except the recurrent state, which is stacked network states
    ``[T_chunk, layers, num_envs, units]``.  Output leaves are ``[num_envs, T_chunk, ...]`` and the state
    ``[num_envs, T_chunk, layers, units]``.
    """
    swap = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731
    data = chunk.replace(recurrent_state=None)
    data = jax.tree.map(swap, data)
    state = jax.tree.map(lambda x: jnp.moveaxis(x, 2, 0), chunk.recurrent_state)
    return data.replace(recurrent_state=state)


@struct.dataclass
class SequenceBatch:
    """``B`` sampled windows of ``L`` consecutive steps of one env each, in the form the learner consumes.

    Observation-indexed fields have ``L`` entries per window, transition-indexed ones ``L - 1`` (transition t goes
    from obs t to obs t+1; the last step's action and reward describe a transition out of the window: dropped).

    Attributes:
      obs: ``[B, L, H, W, C]`` float32 in [0, 1].
      reset: ``[B, L]`` bool, the network zeroes its carry before consuming obs t (= stored ``is_first``).
      action: ``[B, L-1]`` int32 action of transition t.
      reward: ``[B, L-1]`` float32 reward of transition t.
      terminated: ``[B, L-1]`` bool, obs t+1 is terminal.
      truncated: ``[B, L-1]`` bool, the time limit ended the episode at obs t+1.
      loss_mask: ``[B, L-1]`` bool, transition t trains (see :func:`loss_mask`).
      start_state: the stored recurrent state before obs 0, in the network's layout: leaves ``[layers, B, units]``.
      privileged: ``[B, L, K]`` the stored privileged state per obs (None when not stored).
      expert_action: ``[B, L-1]`` int32 the labeller's action at obs t of transition t (None when not stored).
      indices: ``[B]`` int32 the windows' items in a prioritised buffer (for
        :meth:`SequenceReplay.set_priorities`; None when sampling is uniform).
      weights: ``[B]`` float32 importance weights of the windows, at most 1 (None when sampling is uniform).
      burn_in: static number of leading steps that only warm up the carry (``loss_mask`` is False there).
    """

    obs: jax.Array
    reset: jax.Array
    action: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    loss_mask: jax.Array
    start_state: Any
    privileged: jax.Array | None = None
    expert_action: jax.Array | None = None
    indices: jax.Array | None = None
    weights: jax.Array | None = None
    burn_in: int = struct.field(pytree_node=False, default=0)


def loss_mask(is_first: jax.Array, burn_in: int) -> jax.Array:
    """Which transitions of a window train.

    Args:
      is_first: ``[B, L]`` bool from a sampled window.
      burn_in: static number of leading transitions used only to warm up the carry (no loss).

    Returns:
      ``[B, L-1]`` bool: transition t (obs t -> obs t+1) trains iff ``t >= burn_in`` and obs t+1 is not an
      episode's first observation (that transition crosses into the next episode).
    """
    chex.assert_rank(is_first, 2)
    L = is_first.shape[1]
    if not 0 <= burn_in < L - 1:
        raise ValueError(f"burn_in must be in [0, L - 1 = {L - 1}) so that some transition trains, got {burn_in}")
    after_burn_in = jnp.arange(L - 1) >= burn_in  # [L-1]
    return after_burn_in[None, :] & ~is_first.astype(bool)[:, 1:]


def sequence_batch(window: Transition, burn_in: int) -> SequenceBatch:
    """Sampled windows (leaves ``[B, L, ...]``, obs float, state leaves ``[B, L, layers, units]``) -> the
    :class:`SequenceBatch` the learner takes (what :meth:`SequenceReplay.sample` returns)."""
    transition = lambda x: x[:, :-1]  # noqa: E731
    # only the window's first state is needed: the network carries its own state from there
    start = jax.tree.map(lambda x: jnp.moveaxis(x[:, 0], 0, 1), window.recurrent_state)
    return SequenceBatch(
        obs=window.obs,
        reset=window.is_first.astype(bool),
        action=transition(window.action),
        reward=transition(window.reward),
        terminated=transition(window.terminated),
        truncated=transition(window.truncated),
        loss_mask=loss_mask(window.is_first, burn_in),
        start_state=start,
        privileged=window.privileged,
        expert_action=None if window.expert_action is None else transition(window.expert_action),
        burn_in=burn_in,
    )


def _storage_example(example: Transition, config: ReplayConfig) -> Transition:
    """One stored step (no prefix) with the storage dtypes, as zeros."""
    state_dtype = _STATE_DTYPES[config.state_dtype]
    return Transition(
        obs=jnp.zeros(example.obs.shape, _OBS_DTYPES[config.obs_dtype]),
        action=jnp.zeros((), jnp.int32),
        reward=jnp.zeros((), jnp.float32),
        terminated=jnp.zeros((), bool),
        truncated=jnp.zeros((), bool),
        is_first=jnp.zeros((), bool),
        recurrent_state=jax.tree.map(lambda x: jnp.zeros(x.shape, state_dtype), example.recurrent_state),
        privileged=None if example.privileged is None else jnp.zeros(example.privileged.shape, jnp.float32),
        expert_action=None if example.expert_action is None else jnp.zeros((), jnp.int32),
    )


@dataclasses.dataclass(frozen=True, eq=False)
class SequenceReplay:
    """Pure functions over a flashbax ``TrajectoryBufferState`` (jit/scan friendly; donate the state when jitting
    ``add`` outside a scan, or XLA copies the whole buffer).

    Attributes:
      config: the :class:`ReplayConfig`.
      num_envs: rows of the buffer (the ``add`` batch size).
      steps_per_env: length of each row's circular time axis.
      example: one step (no prefix) as given to :func:`make_replay`; its state dtypes are restored on sample.
      buffer: the underlying ``flashbax`` trajectory buffer.
    """

    config: ReplayConfig
    num_envs: int
    steps_per_env: int
    example: Transition
    buffer: Any

    def init(self, example: Transition | None = None):
        """Empty buffer state.  ``example``: one step without prefix (defaults to the one given to make_replay)."""
        example = self.example if example is None else example
        return self.buffer.init(_storage_example(example, self.config))

    def add(self, state, batch: Transition):
        """Append a chunk with leaves ``[num_envs, T_chunk, ...]`` (obs float [0, 1]) to every env's row."""
        num_envs, t_chunk = batch.obs.shape[:2]
        if num_envs != self.num_envs:
            raise ValueError(f"add: batch has {num_envs} envs on axis 0, the buffer was made for {self.num_envs}")
        if t_chunk > self.steps_per_env:
            raise ValueError(
                f"add: chunk of {t_chunk} steps is longer than the buffer's {self.steps_per_env} steps per env"
            )
        stored = state.experience
        obs = quantise_obs(batch.obs, self.config.obs_dtype)
        rest = jax.tree.map(lambda x, s: x.astype(s.dtype), batch.replace(obs=None), stored.replace(obs=None))
        return self.buffer.add(state, rest.replace(obs=obs))

    def sample(self, state, key: jax.Array) -> SequenceBatch:
        """``batch_size`` windows of ``sequence_length`` consecutive steps of one env each, as a
        :class:`SequenceBatch` (obs float32 in [0, 1], the start state in the example's dtypes; from a prioritised
        buffer also the windows' ``indices`` and importance ``weights`` [B]).  Only valid when :meth:`can_sample`:
        flashbax silently returns empty (zero) data from an under-filled buffer."""
        sample = self.buffer.sample(state, key)
        window = sample.experience
        state_out = jax.tree.map(lambda x, e: x.astype(e.dtype), window.recurrent_state, self.example.recurrent_state)
        window = window.replace(obs=dequantise_obs(window.obs), recurrent_state=state_out)
        batch = sequence_batch(window, self.config.burn_in)
        if not self.config.prioritised:
            return batch
        # The float32 sum tree can drift so that a draw lands on a window of priority 0 (not yet filled, crossing the
        # write head, or padding): such a window gets weight 0, and keeps priority 0 (set_priorities).
        valid = sample.probabilities > 0
        log_w = -self.config.importance_exponent * jnp.log(jnp.where(valid, sample.probabilities, 1.0))
        top = jnp.max(jnp.where(valid, log_w, -jnp.inf))  # in log space: the batch's largest valid weight is 1
        return batch.replace(indices=sample.indices, weights=jnp.where(valid, jnp.exp(log_w - top), 0.0))

    def set_priorities(self, state, batch: SequenceBatch, priorities: jax.Array):
        """The buffer state with the windows of ``batch`` (from :meth:`sample`) given ``priorities`` [B] >= 0 (raised
        to ``priority_exponent`` by flashbax; at least 1e-6, so that a window stays drawable), and the windows the
        sum tree holds at priority 0 (weight 0) left there; unchanged when sampling is uniform."""
        if not self.config.prioritised:
            return state
        valid = batch.weights > 0
        return self.buffer.set_priorities(state, batch.indices, jnp.where(valid, jnp.maximum(priorities, 1e-6), 0.0))

    def sampling_state(self, state):
        """The part of the buffer state that learning changes: the sum tree of a prioritised buffer, else None
        (carry it, not the whole buffer, through a loop of updates)."""
        return state.sum_tree_state if self.config.prioritised else None

    def with_sampling_state(self, state, sampling):
        """``state`` with its :meth:`sampling_state` replaced."""
        return state.replace(sum_tree_state=sampling) if self.config.prioritised else state

    def can_sample(self, state) -> jax.Array:
        """``[]`` bool: every env row holds at least ``max(sequence_length, ceil(min_fill_steps / num_envs))`` steps."""
        return self.buffer.can_sample(state)

    def size(self, state) -> jax.Array:
        """``[]`` int32: env steps currently stored, summed over envs."""
        per_env = jnp.where(state.is_full, self.steps_per_env, state.current_index)
        return (per_env * self.num_envs).astype(jnp.int32)


def make_replay(config: ReplayConfig, num_envs: int, example_transition: Transition) -> SequenceReplay:
    """Build the sequence replay.

    Args:
      config: :class:`ReplayConfig` (validated against ``num_envs``).
      num_envs: number of parallel envs = rows of the buffer = leading axis of every added chunk.
      example_transition: one step without batch/time prefix: ``obs [H, W, C]`` (float or uint8), scalars, and
        ``recurrent_state`` leaves ``[layers, units]``.  Only shapes and the state dtype are used.
    """
    per_env = config.steps_per_env(num_envs)
    if len(example_transition.obs.shape) != 3:
        raise ValueError(
            f"example_transition.obs must be one [H, W, C] observation, got shape {tuple(example_transition.obs.shape)}"
        )
    min_len = max(config.sequence_length, math.ceil(config.min_fill_steps / num_envs))
    sizes = dict(
        add_batch_size=num_envs,
        sample_batch_size=config.batch_size,
        sample_sequence_length=config.sequence_length,
        period=config.period,
        min_length_time_axis=min_len,
        max_length_time_axis=per_env,
    )
    if config.prioritised:
        device = "cpu" if jax.default_backend() == "cpu" else "gpu"  # flashbax's sum-tree update for that device
        buffer = fbx.make_prioritised_trajectory_buffer(
            **sizes, priority_exponent=config.priority_exponent, device=device
        )
    else:
        buffer = fbx.make_trajectory_buffer(**sizes)
    return SequenceReplay(
        config=config, num_envs=num_envs, steps_per_env=per_env, example=example_transition, buffer=buffer
    )


def memory_bytes(config: ReplayConfig, num_envs: int, obs_shape: tuple[int, ...], state_shape: Any) -> int:
    """Exact bytes of the buffer state (computed from its abstract shapes, nothing allocated).

    Args:
      obs_shape: ``(H, W, C)`` of one observation.
      state_shape: shape of the per-env recurrent state: one leaf shape ``(layers, units)``, a list/tuple of leaf
        shapes (e.g. ``[(2, 512), (2, 512)]`` for LSTM c and h), or a pytree of arrays / ``ShapeDtypeStruct``
        (per env, no batch axis).
    """
    if isinstance(state_shape, tuple) and all(isinstance(d, (int, np.integer)) for d in state_shape):
        state = jnp.zeros(state_shape, jnp.float32)
    elif isinstance(state_shape, (list, tuple)) and all(isinstance(s, (tuple, list)) for s in state_shape):
        state = [jnp.zeros(tuple(s), jnp.float32) for s in state_shape]
    else:
        state = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), state_shape)
    scalar = lambda dtype: jnp.zeros((), dtype)  # noqa: E731
    example = Transition(
        obs=jax.ShapeDtypeStruct(tuple(obs_shape), jnp.float32),
        action=scalar(jnp.int32),
        reward=scalar(jnp.float32),
        terminated=scalar(bool),
        truncated=scalar(bool),
        is_first=scalar(bool),
        recurrent_state=state,
    )
    replay = make_replay(config, num_envs, example)
    abstract = jax.eval_shape(replay.init)
    return int(sum(math.prod(x.shape) * np.dtype(x.dtype).itemsize for x in jax.tree.leaves(abstract)))
