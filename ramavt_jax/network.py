"""RAMAVT, DRLAVT and the ablation Q-networks (flax.linen).

Public API::

    cfg = NetworkConfig(variant="ramavt")           # frozen, validated
    net = make_network(cfg)                          # QNetwork
    state = initial_state(cfg, batch, obs_shape)     # RecurrentState (obs_shape: needed by 'drlavt')
    params = net.init(key, obs, reset, state)["params"]
    q, state = net.apply({"params": params}, obs, reset, state)   # obs [B, T, H, W, C], reset [B, T] bool

Variants: 'ramavt' (SE + MHA + LSTM), 'origin' (plain DRQN: conv + LSTM), 'se' (origin + SE),
'mha' (origin + MHA), 'drlavt' (4 stacked frames as channels, no SE/MHA/LSTM, dense 1024 -> 512 -> A).

Forward pass: the conv encoder runs on all B*T frames in ONE batched call; only the LSTM is scanned over
time (one ``nn.scan``), with the carry reset to zeros where ``reset[b, t]`` (episode start) before frame t
is consumed. The same module serves acting (T=1, carried state) and learning (T>1).

Every variant takes ONE image per step, obs [B, T, H, W, C]. DRLAVT stacks frames itself: its
``RecurrentState.frames`` holds the previous ``frame_stack - 1`` frames, which are filled with copies of the
current frame where ``reset`` (gym FrameStack behaviour). The trainer can therefore treat DRLAVT exactly like
the recurrent variants (store the state, burn in, reset at episode starts).

Extension point: the trainer and the greedy policy build the network with a *network factory*
(``NetworkConfig -> flax module``, default :func:`make_network`), so another network plugs in without a config
field. ``QNetwork(config, q_head=...)`` swaps only the output layer (a function of the config and the features,
called inside the module, see :func:`q_outputs`); docs/extending.md has an example.

Backbone block i: conv (no bias, padding k//2) -> 2x2 max-pool (ceil mode) -> SE (all blocks but the last)
-> norm -> ReLU (``pool_first=True``, default: SE and norm run on 4x fewer positions, ~2x faster encoder
backward on this CPU). ``pool_first=False`` gives the *orig* order conv -> SE -> norm -> pool -> ReLU. Shapes follow the input resolution: 64x64 gives a 1x1x128 map, 84 -> 2x2, 128 -> 2x2,
256 -> 4x4 (the MHA's tokens).

Normalisation: 'layer' (default) normalises each frame over (H, W, C) jointly with a per-channel scale and
bias (GroupNorm with one group): frame-local, so acting and learning see identical numbers. 'batch' is
BatchNorm over (frames, H, W): with ``train=False`` (default, acting and targets) it uses the running
averages and is deterministic; with ``train=True`` it uses the statistics of the B*T frames of the call and
updates ``batch_stats`` (apply with ``mutable=["batch_stats"]``) -- so learner outputs then differ from acting
outputs by design. 'none' skips it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import flax
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from ramavt_jax.layers import (
    AttentionGate,
    LSTMStack,
    SqueezeExcite,
    he_init,
    lecun_init,
    make_conv,
    max_pool2,
)
from ramavt_jax.network_config import (  # noqa: F401 (re-exported: network.NetworkConfig is the public name)
    CONV_IMPLS,
    DTYPES,
    NORMS,
    VARIANTS,
    NetworkConfig,
)
from ramavt_jax.network_inputs import (  # noqa: F401 (re-exported: the encoder's input helpers)
    coordinate_planes,
    hit_mask,
    previous_actions,
    stack_frames,
    with_coordinates,
    with_hit_mask,
)


@flax.struct.dataclass
class RecurrentState:
    """Carried network state.

    h, c:   [lstm_layers, B, lstm] LSTM hidden and cell states ([0, B, lstm] for 'drlavt').
    frames: [B, frame_stack - 1, H, W, C] previous frames, oldest first ('drlavt'); [B, 0] otherwise.
    prev_action: [1, B] int32, the action taken after the last consumed obs (NetworkConfig.prev_action; None
        otherwise). Laid out like h and c (B on axis 1) so the replay and the sharding treat all three alike.
    """

    h: jax.Array
    c: jax.Array
    frames: jax.Array
    prev_action: jax.Array | None = None


def initial_state(config: NetworkConfig, batch: int, obs_shape: tuple | None = None) -> RecurrentState:
    """Zero state for ``batch`` sequences. ``obs_shape`` = (H, W, C) of one frame, required for 'drlavt' (its frame
    buffer)."""
    layers = config.lstm_layers if config.recurrent else 0
    h = jnp.zeros((layers, batch, config.lstm), jnp.float32)
    if not config.recurrent and (obs_shape is None or len(obs_shape) != 3):
        raise ValueError(f"initial_state: 'drlavt' needs obs_shape=(H, W, C), got {obs_shape!r}")
    # 'drlavt' with frame_stack 1 keeps [B, 0, H, W, C], which stack_frames concatenates along axis 1
    frames = jnp.zeros((batch, 0) if config.recurrent else (batch, config.frame_stack - 1, *obs_shape), jnp.float32)
    prev_action = jnp.zeros((1, batch), jnp.int32) if config.prev_action else None
    return RecurrentState(h=h, c=h, frames=frames, prev_action=prev_action)


def window_start_frames(config: NetworkConfig, obs: jax.Array) -> jax.Array:
    """The frame history a stored window obs [B, L, H, W, C] starts from, which the replay does not store: none
    ([B, 0]) for the recurrent variants; for 'drlavt' copies of the window's first frame [B, frame_stack - 1, H, W,
    C], replaced with real frames during burn-in (burn_in >= frame_stack - 1 is validated)."""
    if config.recurrent:
        return jnp.zeros((obs.shape[0], 0), jnp.float32)
    return jnp.repeat(obs[:, :1], config.frame_stack - 1, axis=1).astype(jnp.float32)


def record_action(state: RecurrentState, action: jax.Array) -> RecurrentState:
    """``state`` with ``action`` [B] recorded as the last action taken (no-op without the previous-action input)."""
    return state if state.prev_action is None else state.replace(prev_action=action[None].astype(jnp.int32))


class Encoder(nn.Module):
    """Conv backbone (+ MHA gate): frames [N, H, W, C] -> features [N, h * w * C_last (+ C_1 with pooled_skip)].
    Sows block outputs to 'intermediates'."""

    config: NetworkConfig

    @nn.compact
    def __call__(self, x: jax.Array, train: bool = False) -> jax.Array:
        cfg = self.config
        dtype = cfg.jnp_dtype
        x = x.astype(dtype)
        planes = None
        if cfg.coord_channels:  # the hit mask joins the frame; the coordinate planes go to the first conv apart
            x, planes = with_hit_mask(x), coordinate_planes(*x.shape[1:3], dtype)
        n_blocks = len(cfg.channels)
        skip = None
        for i, (ch, k, s, p) in enumerate(zip(cfg.channels, cfg.kernels, cfg.strides, cfg.pools)):
            x = make_conv(ch, k, s, cfg.conv_impl, dtype, name=f"conv{i}")(x, planes if i == 0 else None)
            if p and cfg.pool_first:
                x = max_pool2(x)
            if i == 0 and cfg.pooled_skip:  # [N, C_1]: scales with the input, unlike everything after the norm
                skip = jnp.mean(nn.relu(x), axis=(1, 2))
            if cfg.use_se and i < n_blocks - 1:
                x = SqueezeExcite(cfg.se_reduction, dtype=dtype, name=f"se{i}")(x)
            if cfg.norm == "layer":
                x = nn.LayerNorm(reduction_axes=(1, 2, 3), feature_axes=-1, dtype=dtype, name=f"norm{i}")(x)
            elif cfg.norm == "batch":
                x = nn.BatchNorm(use_running_average=not train, momentum=0.99, dtype=dtype, name=f"norm{i}")(x)
            if p and not cfg.pool_first:
                x = max_pool2(x)
            x = nn.relu(x)
            self.sow("intermediates", f"block{i + 1}", x)
        if cfg.use_mha:
            x = AttentionGate(cfg.attention_heads, dtype=dtype, name="attention")(x)
            self.sow("intermediates", "mha", x)
        x = x.reshape(x.shape[0], -1)
        return x if skip is None else jnp.concatenate([x, skip], axis=-1)


def q_outputs(cfg: NetworkConfig, y: jax.Array) -> jax.Array:
    """Q-values [..., A] from features y [..., F]: one linear layer 'q' (QNetwork's default ``q_head``; called
    inside its compact call, so a replacement may create layers and sow)."""
    return nn.Dense(cfg.num_actions, dtype=cfg.jnp_dtype, kernel_init=lecun_init, name="q")(y)


class QNetwork(nn.Module):
    """Q-network. __call__(obs [B, T, H, W, C], reset [B, T] bool, state, actions [B, T] | None) -> (q [B, T, A]
    float32, state). ``actions`` (taken at each step) matter only with ``prev_action``: the returned state's
    prev_action is then ``actions[:, T - 1]``, else unchanged (acting code records its pick: record_action).
    ``q_head``: the output layer, (config, features [..., F]) -> q [..., A] (default :func:`q_outputs`)."""

    config: NetworkConfig
    q_head: Callable[[NetworkConfig, jax.Array], jax.Array] = q_outputs

    def initial_state(self, batch: int, obs_shape: tuple | None = None) -> RecurrentState:
        return initial_state(self.config, batch, obs_shape)

    @nn.compact
    def __call__(
        self, obs: jax.Array, reset: jax.Array, state: RecurrentState, train: bool = False, actions=None
    ) -> tuple[jax.Array, RecurrentState]:
        cfg = self.config
        if obs.ndim != 5 or reset.shape != obs.shape[:2]:
            raise ValueError(
                f"QNetwork: expected obs [B, T, H, W, C] and reset [B, T], got {obs.shape} and {reset.shape}"
            )
        b, t = obs.shape[:2]
        dtype = cfg.jnp_dtype
        reset = reset.astype(bool)
        frames = state.frames
        if not cfg.recurrent:
            obs, frames = stack_frames(obs, reset, state.frames)
        x = Encoder(cfg, name="encoder")(obs.reshape(b * t, *obs.shape[2:]), train)  # [B*T, F]
        if cfg.recurrent:
            x = nn.relu(nn.Dense(cfg.dense, dtype=dtype, kernel_init=he_init, name="dense")(x)).reshape(b, t, -1)
            prev_action = state.prev_action
            if cfg.prev_action:
                seen = previous_actions(state.prev_action, reset, actions, cfg.num_actions, dtype)
                x = jnp.concatenate([x, seen], axis=-1)
                taken = actions is not None and actions.shape[1] == t  # the last step's action is known
                prev_action = actions[:, -1:].T.astype(jnp.int32) if taken else state.prev_action
            y, (h, c) = LSTMStack(cfg.lstm, cfg.lstm_layers, dtype=dtype, name="lstm")(x, reset, (state.h, state.c))
            if cfg.aux_outputs:  # [B, T, aux_outputs], read by auxiliary losses only
                self.sow("intermediates", "aux", nn.Dense(cfg.aux_outputs, dtype=dtype, name="aux_head")(y))
            y = nn.relu(nn.Dense(cfg.head, dtype=dtype, kernel_init=he_init, name="head")(y))
            q = self.q_head(cfg, y)
            new_state = RecurrentState(h=h, c=c, frames=frames.astype(state.frames.dtype), prev_action=prev_action)
        else:
            for j, width in enumerate(cfg.drlavt_dense):
                x = nn.relu(nn.Dense(width, dtype=dtype, kernel_init=he_init, name=f"dense{j}")(x))
            q = self.q_head(cfg, x)
            new_state = RecurrentState(h=state.h, c=state.c, frames=frames.astype(state.frames.dtype))
        return q.reshape(b, t, cfg.num_actions).astype(jnp.float32), new_state


def make_network(config: NetworkConfig) -> QNetwork:
    """The default network factory: the QNetwork of ``config``."""
    return QNetwork(config)


def init_variables(net: nn.Module, config: NetworkConfig, key: jax.Array, obs_shape: tuple) -> dict:
    """The variables of ``net`` (any network factory's module for ``config``) for frames of shape (H, W, C), from
    one step of one sequence: ``{'params': ...}`` (plus ``'batch_stats'`` for norm='batch'). Not jitted."""
    obs = jnp.zeros((1, 1, *obs_shape), jnp.float32)
    reset = jnp.ones((1, 1), bool)
    variables = net.init(key, obs, reset, initial_state(config, 1, tuple(obs_shape)))
    return {k: v for k, v in variables.items() if k != "intermediates"}


def init_params(config: NetworkConfig, key: jax.Array, obs_shape: tuple) -> dict:
    """Initialise the default network's variables for frames of shape (H, W, C) (jitted; see init_variables)."""
    return _init_jit(config, tuple(obs_shape), key)


@functools.partial(jax.jit, static_argnums=(0, 1))
def _init_jit(config: NetworkConfig, obs_shape: tuple, key: jax.Array) -> dict:
    return init_variables(make_network(config), config, key, obs_shape)


def count_params(params) -> int:
    """Number of scalars in a parameter (or variable) tree."""
    return int(sum(np.prod(np.shape(x)) for x in jax.tree_util.tree_leaves(params)))


def flops_per_frame(config: NetworkConfig, obs_shape: tuple) -> int:
    """Forward FLOPs for one frame (B=1, T=1), from XLA's cost analysis of the jitted forward.

    obs_shape: (H, W, C) of one frame (for 'drlavt' the single frame; stacking is internal).
    """
    net = make_network(config)
    variables = jax.eval_shape(lambda k: init_params(config, k, obs_shape), jax.random.key(0))
    obs = jax.ShapeDtypeStruct((1, 1, *obs_shape), jnp.float32)
    reset = jax.ShapeDtypeStruct((1, 1), jnp.bool_)
    state = jax.eval_shape(lambda: initial_state(config, 1, obs_shape))
    fn = jax.jit(lambda v, o, r, s: net.apply(v, o, r, s)[0])
    cost = fn.lower(variables, obs, reset, state).compile().cost_analysis()
    if isinstance(cost, (list, tuple)):
        cost = cost[0]
    return int(cost.get("flops", 0))


def attention_maps(params, config: NetworkConfig, obs: jax.Array, variables: dict | None = None) -> dict:
    """Activation-attention maps (Zagoruyko & Komodakis) for one frame obs [H, W, C].

    For each conv block ('block1'..'blockN') and the MHA output ('mha', attention variants only): sum of squared
    activations over channels, then a softmax over all h*w positions. Returns {name: [h, w]}, each summing to 1.
    Pass the full ``variables`` dict instead of ``params`` when norm='batch'.
    """
    if variables is None:
        variables = {"params": params}
    net = make_network(config)
    obs = jnp.asarray(obs, jnp.float32)
    state = initial_state(config, 1, obs.shape)
    _, mut = net.apply(variables, obs[None, None], jnp.ones((1, 1), bool), state, mutable=["intermediates"])
    inter = mut["intermediates"]["encoder"]
    maps = {}
    for name, (act,) in inter.items():
        energy = jnp.sum(jnp.square(act[0].astype(jnp.float32)), axis=-1)  # [h, w]
        maps[name] = jax.nn.softmax(energy.reshape(-1)).reshape(energy.shape)
    return maps


__all__ = [
    "NetworkConfig",
    "RecurrentState",
    "QNetwork",
    "q_outputs",
    "initial_state",
    "make_network",
    "init_variables",
    "init_params",
    "count_params",
    "flops_per_frame",
    "attention_maps",
    "stack_frames",
    "previous_actions",
    "with_coordinates",
    "window_start_frames",
    "record_action",
]
