"""RAMAVT, DRLAVT and the ablation Q-networks (flax.linen).

Public API::

    cfg = NetworkConfig(variant="ramavt")           # frozen, validated
    net = make_network(cfg)                          # QNetwork
    state = initial_state(cfg, batch, obs_shape)     # RecurrentState (obs_shape: drlavt, frame/exposure inputs)
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
    TRUE_STATE_SIZE,
    VARIANTS,
    NetworkConfig,
)
from ramavt_jax.network_inputs import (  # noqa: F401 (re-exported: the encoder's input helpers)
    coordinate_planes,
    frame_changes,
    hit_mask,
    long_exposure,
    silhouette_stats,
    with_coordinates,
    with_depth_rescaled,
    with_hit_mask,
)


@flax.struct.dataclass
class RecurrentState:
    """Carried network state.

    h, c:   [lstm_layers, B, lstm] LSTM hidden and cell states ([0, B, lstm] for 'drlavt').
    frames: [B, frame_stack - 1, H, W, C] previous frames, oldest first ('drlavt'); [B, 1, H, W, C] the previous
        frame (frame_difference); [B, 0] otherwise.
    prev_action: [1, B] int32, the action taken after the last consumed obs (NetworkConfig.prev_action; None
        otherwise). Laid out like h and c (B on axis 1) so the replay and the sharding treat all three alike.
    exposure: [1, B, H, W, C + 1] the long exposure after the last consumed obs (NetworkConfig.exposure_rate; None
        otherwise), laid out and stored like prev_action.
    """

    h: jax.Array
    c: jax.Array
    frames: jax.Array
    prev_action: jax.Array | None = None
    exposure: jax.Array | None = None


def initial_state(config: NetworkConfig, batch: int, obs_shape: tuple | None = None) -> RecurrentState:
    """Zero state for ``batch`` sequences. ``obs_shape`` = (H, W, C) of one frame, required for 'drlavt',
    frame_difference (their frame buffers) and exposure_rate (its average)."""
    layers = config.lstm_layers if config.recurrent else 0
    h = jnp.zeros((layers, batch, config.lstm), jnp.float32)
    no_buffer = config.recurrent and not config.frame_difference
    if (not no_buffer or config.exposure_rate) and (obs_shape is None or len(obs_shape) != 3):
        raise ValueError(
            f"initial_state: {config.variant!r} with frame_difference={config.frame_difference}, "
            f"exposure_rate={config.exposure_rate} needs obs_shape=(H, W, C), got {obs_shape!r}"
        )
    # 'drlavt' with frame_stack 1 keeps [B, 0, H, W, C], which stack_frames concatenates along axis 1
    frames = jnp.zeros((batch, 0) if no_buffer else (batch, _kept_frames(config), *obs_shape), jnp.float32)
    prev_action = jnp.zeros((1, batch), jnp.int32) if config.prev_action else None
    exposure = None
    if config.exposure_rate:
        exposure = jnp.zeros((1, batch, *obs_shape[:2], obs_shape[2] + 1), jnp.float32)
    return RecurrentState(h=h, c=h, frames=frames, prev_action=prev_action, exposure=exposure)


def _kept_frames(config: NetworkConfig) -> int:
    """How many previous frames RecurrentState.frames holds: frame_stack - 1 ('drlavt'), 1 (frame_difference), 0."""
    if not config.recurrent:
        return config.frame_stack - 1
    return 1 if config.frame_difference else 0


def window_start_frames(config: NetworkConfig, obs: jax.Array) -> jax.Array:
    """The frame history a stored window obs [B, L, H, W, C] starts from, which the replay does not store: none
    ([B, 0]) for the recurrent variants without frame_difference; else copies of the window's first frame [B, K, H,
    W, C] (K = _kept_frames), replaced with real frames during burn-in (burn_in >= frame_stack - 1 for 'drlavt' and
    >= 1 with frame_difference are validated: the window's first step sees no change, and is not trained)."""
    if config.recurrent and not config.frame_difference:
        return jnp.zeros((obs.shape[0], 0), jnp.float32)
    return jnp.repeat(obs[:, :1], _kept_frames(config), axis=1).astype(jnp.float32)


def record_action(state: RecurrentState, action: jax.Array) -> RecurrentState:
    """``state`` with ``action`` [B] recorded as the last action taken (no-op without the previous-action input)."""
    return state if state.prev_action is None else state.replace(prev_action=action[None].astype(jnp.int32))


def previous_actions(
    config: NetworkConfig, reset: jax.Array, state: RecurrentState, actions: jax.Array | None
) -> jax.Array:
    """One-hot previous action per step [B, T, A + 1]: state.prev_action before step 0, ``actions[:, t - 1]`` (
    [B, T] or [B, T - 1], needed when T > 1) before step t > 0, the extra 'none' entry A where ``reset``."""
    b, t = reset.shape
    prev = state.prev_action[0][:, None]  # [B, 1]
    if t > 1:
        if actions is None or actions.shape[1] not in (t - 1, t):
            raise ValueError(
                f"QNetwork: a prev_action network needs the window's actions [B, T] or [B, T - 1] "
                f"when T > 1, got {None if actions is None else actions.shape} for T = {t}"
            )
        prev = jnp.concatenate([prev, actions[:, : t - 1].astype(prev.dtype)], axis=1)
    prev = jnp.where(reset, config.num_actions, prev)
    return jax.nn.one_hot(prev, config.num_actions + 1, dtype=config.jnp_dtype)


def stack_frames(obs: jax.Array, reset: jax.Array, frames: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Frame stacking along T. obs [B, T, H, W, C], reset [B, T], frames [B, K-1, H, W, C] (oldest first).

    Returns stacked [B, T, H, W, K*C] (channels oldest..newest) and the new buffer. Where reset[b, t] the
    history is replaced by copies of frame t. Only moves memory: cheap to scan.
    """
    k1 = frames.shape[1]

    def step(hist, inp):
        x, r = inp  # [B, H, W, C], [B]
        hist = jnp.where(r[:, None, None, None, None], x[:, None], hist)
        full = jnp.concatenate([hist, x[:, None]], axis=1)  # [B, K, H, W, C]
        b, k, h, w, c = full.shape
        stacked = jnp.moveaxis(full, 1, 3).reshape(b, h, w, k * c)
        return full[:, 1:] if k1 else hist, stacked

    hist, stacked = jax.lax.scan(step, frames.astype(obs.dtype), (jnp.swapaxes(obs, 0, 1), reset.T))
    return jnp.swapaxes(stacked, 0, 1), hist


class Encoder(nn.Module):
    """Conv backbone (+ MHA gate): [N, H, W, C] -> [N, h * w * C_last (+ C_1 with pooled_skip) (+ 8 with
    silhouette_stats)].
    Sows block outputs to 'intermediates'."""

    config: NetworkConfig

    @nn.compact
    def __call__(self, x: jax.Array, train: bool = False, extra: jax.Array | None = None) -> jax.Array:
        """x [N, H, W, C] frames; extra [N, H, W, E] channels computed over time (frame_difference's changes,
        then the long exposure), appended as input channels after the hit mask."""
        cfg = self.config
        dtype = cfg.jnp_dtype
        stats = silhouette_stats(x).astype(dtype) if cfg.silhouette_stats else None
        x = x.astype(dtype)
        planes = None
        if cfg.coord_channels:  # the hit mask joins the frame; the coordinate planes go to the first conv apart
            hit = hit_mask(x)  # of the raw frame: a centred target pixel may read 0
            if cfg.rescales_depth:
                x = with_depth_rescaled(x, hit, cfg.depth_centre, cfg.depth_gain)
            x, planes = jnp.concatenate([x, hit], axis=-1), coordinate_planes(*x.shape[1:3], dtype)
        if extra is not None:
            x = jnp.concatenate([x, extra.astype(dtype)], axis=-1)
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
        extras = [f for f in (skip, stats) if f is not None]
        return jnp.concatenate([x.reshape(x.shape[0], -1), *extras], axis=-1)


class QNetwork(nn.Module):
    """Q-network. __call__(obs [B, T, H, W, C], reset [B, T] bool, state, actions [B, T] | None, standoff [B, T] |
    None, true_state [B, T, 6] | None) -> (q [B, T, A] float32, state); with ``policy_head`` q is the policy's logits
    (argmax: the greedy action), Q sown as intermediates 'q_values' [B, T, A]. ``actions`` (taken at each step)
    matter only with ``prev_action``: the returned state's prev_action is then ``actions[:, T - 1]``, else unchanged
    (acting code records its pick: record_action). ``standoff`` (each step's stand-off signal,
    greedy.standoff_signal: the scale k or the command gain, 1 for catalogue targets) is needed with
    ``standoff_input`` or ``command_gain_input``, ignored without; ``true_state`` [B, T, 6]
    (greedy.tracking_state_of per step) with ``state_input``, ignored without."""

    config: NetworkConfig

    def initial_state(self, batch: int, obs_shape: tuple | None = None) -> RecurrentState:
        return initial_state(self.config, batch, obs_shape)

    @nn.compact
    def __call__(
        self,
        obs: jax.Array,
        reset: jax.Array,
        state: RecurrentState,
        train: bool = False,
        actions: jax.Array | None = None,
        standoff: jax.Array | None = None,
        true_state: jax.Array | None = None,
    ):
        cfg = self.config
        if obs.ndim != 5 or reset.shape != obs.shape[:2]:
            raise ValueError(
                f"QNetwork: expected obs [B, T, H, W, C] and reset [B, T], got {obs.shape} and {reset.shape}"
            )
        b, t = obs.shape[:2]
        dtype = cfg.jnp_dtype
        reset = reset.astype(bool)
        extra, frames, exposure = [], state.frames, state.exposure
        if not cfg.recurrent:
            obs, frames = stack_frames(obs, reset, state.frames)
        if cfg.frame_difference:
            changes, frames = frame_changes(obs, reset, state.frames)
            extra.append(changes)
        if cfg.exposure_rate:
            exposures = long_exposure(obs, reset, state.exposure[0], cfg.exposure_rate)  # [B, T, H, W, C + 1]
            extra, exposure = extra + [exposures], exposures[:, -1][None]
        extra = jnp.concatenate(extra, axis=-1).reshape(b * t, *obs.shape[2:4], -1) if extra else None
        x = Encoder(cfg, name="encoder")(obs.reshape(b * t, *obs.shape[2:]), train, extra)  # [B*T, F]
        if cfg.recurrent:
            x = nn.Dense(cfg.dense, dtype=dtype, kernel_init=he_init, name="dense")(x)
            x = nn.relu(_maybe_norm(cfg, "dense_norm", x)).reshape(b, t, -1)
            prev_action = state.prev_action
            if cfg.prev_action:
                x = jnp.concatenate([x, previous_actions(cfg, reset, state, actions)], axis=-1)
                taken = actions is not None and actions.shape[1] == t  # the last step's action is known
                prev_action = actions[:, -1:].T.astype(jnp.int32) if taken else state.prev_action
            if cfg.reads_standoff:
                x = jnp.concatenate([x, standoff_feature(standoff, reset.shape)[..., None].astype(dtype)], axis=-1)
            if cfg.state_input:
                seen = true_state_feature(true_state, reset.shape) * cfg.state_input_gain * cfg.state_input_mask
                x = jnp.concatenate([x, seen.astype(dtype)], axis=-1)
            y, (h, c) = LSTMStack(cfg.lstm, cfg.lstm_layers, dtype=dtype, name="lstm")(x, reset, (state.h, state.c))
            if cfg.aux_outputs:  # [B, T, aux_outputs], read by auxiliary losses only
                self.sow("intermediates", "aux", nn.Dense(cfg.aux_outputs, dtype=dtype, name="aux_head")(y))
            y = nn.Dense(cfg.head, dtype=dtype, kernel_init=he_init, name="head")(y)
            y = nn.relu(_maybe_norm(cfg, "head_norm", y))
            q = q_outputs(cfg, y)
            if cfg.policy_head:  # acting takes the logits' argmax, the TD loss Q (NetworkConfig.policy_head)
                self.sow("intermediates", "q_values", q.astype(jnp.float32))
                q = nn.Dense(cfg.num_actions, dtype=dtype, kernel_init=lecun_init, name="policy")(y)
            new_state = RecurrentState(
                h=h, c=c, frames=frames.astype(state.frames.dtype), prev_action=prev_action, exposure=exposure
            )
        else:
            for j, width in enumerate(cfg.drlavt_dense):
                x = nn.relu(nn.Dense(width, dtype=dtype, kernel_init=he_init, name=f"dense{j}")(x))
            q = q_outputs(cfg, x)
            new_state = RecurrentState(h=state.h, c=state.c, frames=frames.astype(state.frames.dtype))
        if cfg.quantiles:  # the loss reads the quantiles; acting, the mean
            q = q.astype(jnp.float32)
            self.sow("intermediates", "quantiles", q.reshape(b, t, cfg.num_actions, cfg.quantiles))
            q = q.mean(-1)
        return q.reshape(b, t, cfg.num_actions).astype(jnp.float32), new_state


def _maybe_norm(cfg: NetworkConfig, name: str, x: jax.Array) -> jax.Array:
    """x [..., F] through a LayerNorm over F named ``name`` with ``cfg.dense_norm`` (in QNetwork's compact call)."""
    return nn.LayerNorm(dtype=cfg.jnp_dtype, name=name)(x) if cfg.dense_norm else x


def standoff_feature(standoff: jax.Array | None, shape: tuple[int, int]) -> jax.Array:
    """[B, T] ln of each step's stand-off signal standoff [B, T] (greedy.standoff_signal: k or the command gain);
    refuses a missing one (1 is passed, not assumed: a caller that forgets it would act on the wrong size unnoticed)."""
    if standoff is None or standoff.shape != tuple(shape):
        raise ValueError(
            f"QNetwork: this network needs standoff [B, T] = {tuple(shape)} (the episodes' "
            f"stand-off signal), got {None if standoff is None else standoff.shape}"
        )
    return jnp.log(standoff)


def true_state_feature(true_state: jax.Array | None, shape: tuple[int, int]) -> jax.Array:
    """[B, T, 6] the true state as given; refuses a missing or misshapen one (zeros would pass for a target held
    exactly in place)."""
    want = (*shape, TRUE_STATE_SIZE)
    if true_state is None or true_state.shape != want:
        got = None if true_state is None else true_state.shape
        raise ValueError(
            f"QNetwork: a state_input network needs true_state [B, T, {TRUE_STATE_SIZE}] = {want} "
            f"(greedy.tracking_state_of per step), got {got}"
        )
    return true_state


def q_outputs(cfg: NetworkConfig, y: jax.Array) -> jax.Array:
    """Q-values [..., A] from features y [..., F] (inside QNetwork's compact call): one linear layer 'q'; with
    ``cfg.quantiles`` N of them per action [..., A, N]; with ``cfg.dueling`` a value 'value' plus the mean-centred
    outputs of 'q' (every sample trains the value; the few-cm gaps between actions are learned apart from it)."""
    if cfg.quantiles:  # [..., A, N]
        z = nn.Dense(cfg.num_actions * cfg.quantiles, dtype=cfg.jnp_dtype, kernel_init=lecun_init, name="q")(y)
        return z.reshape(*z.shape[:-1], cfg.num_actions, cfg.quantiles)
    q = nn.Dense(cfg.num_actions, dtype=cfg.jnp_dtype, kernel_init=lecun_init, name="q")(y)
    if not cfg.dueling:
        return q
    value = nn.Dense(1, dtype=cfg.jnp_dtype, kernel_init=lecun_init, name="value")(y)
    return value + q - q.mean(axis=-1, keepdims=True)


def _dummy_signals() -> dict:
    """Per-step signals (standoff [1, 1], true_state [1, 1, 6]) for a single-frame call that only needs shapes or
    the encoder (init, cost, maps)."""
    return dict(standoff=jnp.ones((1, 1)), true_state=jnp.zeros((1, 1, TRUE_STATE_SIZE)))


def make_network(config: NetworkConfig) -> QNetwork:
    return QNetwork(config)


def init_params(config: NetworkConfig, key: jax.Array, obs_shape: tuple) -> dict:
    """Initialise variables for frames of shape (H, W, C) (jitted). Returns the full variable dict
    (``{'params': ...}`` plus ``'batch_stats'`` for norm='batch')."""
    return _init_jit(config, tuple(obs_shape), key)


@functools.partial(jax.jit, static_argnums=(0, 1))
def _init_jit(config: NetworkConfig, obs_shape: tuple, key: jax.Array) -> dict:
    net = make_network(config)
    obs = jnp.zeros((1, 1, *obs_shape), jnp.float32)
    reset = jnp.ones((1, 1), bool)
    variables = net.init(key, obs, reset, initial_state(config, 1, obs_shape), **_dummy_signals())
    return {k: v for k, v in variables.items() if k != "intermediates"}


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
    fn = jax.jit(lambda v, o, r, s: net.apply(v, o, r, s, **_dummy_signals())[0])
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
    _, mut = net.apply(
        variables, obs[None, None], jnp.ones((1, 1), bool), state, **_dummy_signals(), mutable=["intermediates"]
    )
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
    "initial_state",
    "make_network",
    "init_params",
    "count_params",
    "flops_per_frame",
    "attention_maps",
    "stack_frames",
    "with_coordinates",
    "window_start_frames",
]
