"""The Q-network's configuration: one frozen, validated dataclass (the network itself: :mod:`ramavt_jax.network`,
which re-exports these names)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ramavt_jax.layers import conv_out_size

VARIANTS = ("ramavt", "drlavt", "origin", "se", "mha")
NORMS = ("batch", "layer", "none")
CONV_IMPLS = ("hybrid", "im2col", "lax")
DTYPES = {"float32": jnp.float32, "bfloat16": jnp.bfloat16}
TRUE_STATE_SIZE = 6  # NetworkConfig.state_input: tracking error [3] and relative velocity [3]
STATE_INPUT_POINTS = ("centre", "visible", "image")  # NetworkConfig.state_input_point


# Switches that only a recurrent variant has, with why ('drlavt' stacks frames into one conv input and has no LSTM).
_RECURRENT_ONLY = {
    "aux_outputs": "the head reads the LSTM output",
    "silhouette_stats": "one frame per encoder input",
    "dense_norm": "it normalises the dense layer and head around the LSTM",
    "prev_action": "the previous action is an LSTM input",
    "state_input": "an LSTM input",
    "exposure_rate": "its average rides in the recurrent state",
    "frame_difference": "the previous frame rides in the recurrent state; 'drlavt' has frame_stack",
}


def _fail(msg: str):
    raise ValueError(f"NetworkConfig: {msg}")


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Q-network hyper-parameters (docs/design.md lists where they depart from the original). Validated on
    construction."""

    variant: str = "ramavt"
    num_actions: int = 11
    channels: tuple = (32, 64, 128, 128)
    kernels: tuple = (3, 3, 3, 1)
    strides: tuple = (2, 2, 1, 1)
    pools: tuple = (True, True, True, True)  # 2x2 max-pool in block i
    pool_first: bool = (
        True  # conv -> pool -> SE -> norm -> ReLU (fast); False: *orig* conv -> SE -> norm -> pool -> ReLU
    )
    norm: str = "layer"
    se_reduction: int = 8
    attention_heads: int = 8
    dense: int = 512
    lstm: int = 512
    lstm_layers: int = 2
    head: int = 256
    drlavt_dense: tuple = (1024, 512)
    frame_stack: int = 4  # drlavt only
    conv_impl: str = "hybrid"  # or "im2col" | "lax": the same parameters, other speed (layers.CONV_FUNCTIONS)
    dtype: str = "float32"
    # Absolute depth and image position made visible to the encoder (see Encoder): without these, a bias-free conv
    # followed by a per-frame LayerNorm is exactly invariant to a global scaling of the depth image.
    coord_channels: bool = False  # append a hit mask and the pixel coordinates in [-1, 1] to the input channels
    pooled_skip: bool = False  # append the spatial mean of block 1's activations, taken BEFORE its norm, to the output
    # The depth channel on the target's pixels as (depth - depth_centre) * depth_gain before the first conv (the
    # background stays 0; needs coord_channels, whose hit mask then tells a pixel at depth_centre from the
    # background). In depth / far units a 0.1 m range change at the 5 m stand-off is 0.005 (far 20 m), too small for
    # the first layer's initial weights (He: std about 0.18) and a few thousand Adam steps to amplify: centre 0.25 and
    # gain 20 give metres from the stand-off. 0 and 1: the observation as it is.
    depth_centre: float = 0.0
    depth_gain: float = 1.0
    # Append eight statistics of the target's silhouette in the current frame to the encoder's output (see
    # network_inputs.silhouette_stats): its size, centroid and spread in pixels, and its mean, nearest and spread of depth
    # in metres from the stand-off. Convs with patch strides see the silhouette at 4-pixel granularity, and depth
    # within a target only as a small offset; these carry both at the observation's precision, as the classical
    # tracker reads them. Recurrent variants only ('drlavt' stacks frames before the encoder).
    silhouette_stats: bool = False
    prev_action: bool = False  # R2D2's LSTM input: the previous action (one-hot; a 'none' entry at episode starts)
    # The episode's stand-off scale k (EnvParams.standoff_per_radius; 1 for every catalogue target) as ln k beside
    # the encoder's features at the LSTM's input. The image of a target at scale k is the image of the target scaled
    # by 1/k at 1/k of the distance: k cannot be read from a frame, only from how fast the view moves, and a command
    # moves the view of a small target 1/k times as far. Recurrent variants only; the caller passes k per step.
    standoff_input: bool = False
    # Instead of ln k, ln of how far a command moves the view in the episode's stand-off units against a catalogue
    # target's (env.command_gain: 1 / k for small targets, 1 for large ones under the default speed rule): the
    # quantity a frame cannot show, in a range that training on small sizes covers for every size.
    command_gain_input: bool = False
    # A linear head of this many outputs on the LSTM output, sown as intermediates 'aux' (apply with
    # mutable=["intermediates"]): the trainer fits it to the true tracking error (3), and with 6 also to the relative
    # velocity (LearnerConfig.aux_weight). 0 = none.
    aux_outputs: int = 0
    dueling: bool = False  # Q = V + A - mean(A) (dueling head, Wang et al. 2016; see network.q_outputs)
    # N quantiles of the return per action (QR-DQN, Dabney et al. 2018; 0 = expected values only): the head outputs
    # A * N values, sown as intermediates 'quantiles' [B, T, A, N] for the quantile loss; Q is their mean.
    quantiles: int = 0
    # A policy head beside Q, as a student distilled from a privileged teacher (Chen et al. 2019, "Learning by
    # Cheating"): A logits from the head's features, fitted by cross-entropy to the true-state look-ahead's labels
    # (LearnerConfig.policy_weight). The network returns the logits, whose argmax every acting path takes, and sows
    # Q as intermediates 'q_values' for the TD loss. Recurrent variants only; not with quantiles.
    policy_head: bool = False
    # LayerNorm between the dense layer and its ReLU, and between the head and its ReLU (PQN's normalisation of the
    # value network, Gallici et al. 2024, who credit it with stable bootstrapping from the online net; on the quick
    # preset it lost, lab/experiments.md arm dense-norm). Recurrent variants only.
    dense_norm: bool = False
    # A diagnostic, not a tracker: the true tracking error and relative velocity (TRUE_STATE_SIZE numbers in
    # stand-off distances, greedy.true_tracking_state) beside the encoder's features at the LSTM's input, read from
    # the simulator at every step (the caller passes true_state [B, T, 6]). Trained so, the agent measures how far
    # this learner gets with perfect perception at a budget: the part of the gap to the ceiling that is not in the
    # images. Recurrent variants only. (With state_input_point 'image' the same input carries what the frame shows
    # instead, and the network is a tracker.)
    state_input: bool = False
    # The true state times this at the LSTM's input (state_input only). In stand-off distances a 0.05 m error reads
    # 0.01 beside features of order 1: a gain asks whether the diagnostic's shortfall is the learner's or the scale's.
    state_input_gain: float = 1.0
    # Which of the TRUE_STATE_SIZE entries the network reads (state_input only; the others read 0): 0-2 the error
    # across the image (x, y) and along the boresight (z), 3-5 the relative velocity likewise. A subset asks which
    # part of the state the images fail to give.
    state_input_entries: tuple[int, ...] = tuple(range(TRUE_STATE_SIZE))
    # Which point the state's error is measured to (state_input only): 'centre', the target's centre of mass (the
    # reward's point), or 'visible', the centroid of its visible surface in the newest frame
    # (greedy.visible_tracking_state): what a perfect reading of the images' surface would give, without the centre;
    # or 'image', the same centroid computed from the frame alone (zeros on a blank frame), not a diagnostic: a
    # tracker input, with state_input_entries among the error's 0-2 (the velocity reads 0).
    state_input_point: str = "centre"
    # A motion cue: the change of each pixel since the previous frame (0 at an episode's first step) as one more input
    # channel per observation channel, beside the hit mask. Velocity otherwise has to be read by the LSTM from two
    # pooled feature vectors; here the first conv sees the target's edges move and its surface come nearer. The
    # previous frame rides in RecurrentState.frames (not stored in the replay: a stored window starts with no
    # change, inside the burn-in). Recurrent variants only ('drlavt' stacks whole frames).
    frame_difference: bool = False
    # A long exposure: the frame and its hit mask averaged exponentially over the episode, 1 / exposure_rate steps
    # long (network_inputs.long_exposure), as more input channels. The reward measures the centre of mass, about
    # which a tumbling target turns; one silhouette does not show it, a region swept over seconds comes nearer. The
    # average rides in RecurrentState.exposure and is stored in the replay with the LSTM state, in float32: (C + 1)
    # * 4 bytes per pixel and step beside the uint8 frame's C (8x its memory for depth). 0: off. Recurrent variants
    # only; not with augmentation (the stored average is of the frames as flown).
    exposure_rate: float = 0.0

    def __post_init__(self):
        if self.variant not in VARIANTS:
            _fail(f"variant={self.variant!r} is not one of {VARIANTS}")
        for name, allowed in (("norm", NORMS), ("conv_impl", CONV_IMPLS), ("dtype", tuple(DTYPES))):
            if getattr(self, name) not in allowed:
                _fail(f"{name}={getattr(self, name)!r} is not one of {allowed}")
        self._check_encoder()
        for name in (
            "num_actions",
            "se_reduction",
            "attention_heads",
            "dense",
            "lstm",
            "lstm_layers",
            "head",
            "frame_stack",
        ):
            v = getattr(self, name)
            if not _is_int(v) or v < 1:
                _fail(f"{name} must be a positive integer, got {v!r}")
        if self.use_mha and self.channels[-1] % self.attention_heads != 0:
            _fail(
                f"attention_heads={self.attention_heads} must divide the last block's channels "
                f"({self.channels[-1]}) for variant {self.variant!r}"
            )
        if not _is_int(self.aux_outputs) or self.aux_outputs < 0:
            _fail(f"aux_outputs must be an integer >= 0, got {self.aux_outputs!r}")
        for name in ("depth_centre", "depth_gain"):
            if not _is_number(getattr(self, name)) or not np.isfinite(getattr(self, name)):
                _fail(f"{name} must be a finite number, got {getattr(self, name)!r}")
        if not self.depth_gain > 0:
            _fail(f"depth_gain must be > 0 (1 = the observation as it is), got {self.depth_gain!r}")
        if self.rescales_depth and not self.coord_channels:
            _fail(
                "depth_centre / depth_gain need coord_channels=True: once centred, a target pixel at depth_centre "
                "reads 0 like the background, and only the hit mask tells them apart"
            )
        if not _is_int(self.quantiles) or self.quantiles == 1 or self.quantiles < 0:
            _fail(f"quantiles must be 0 (expected values) or an integer >= 2, got {self.quantiles!r}")
        if self.policy_head and (self.quantiles or not self.recurrent):
            _fail("policy_head needs a recurrent variant (the head reads the LSTM output) and no quantiles")
        if self.quantiles and self.dueling:
            _fail("quantiles and dueling are not combined (a dueling head of quantiles is not defined here)")
        if self.standoff_input and self.command_gain_input:
            _fail("standoff_input and command_gain_input are two forms of one input: choose one")
        r = self.exposure_rate
        if not _is_number(r) or not 0 <= r <= 1:
            _fail(f"exposure_rate must be a number in [0, 1] (0: off), got {r!r}")
        self._check_state_input()
        if not self.recurrent:
            for name, why in _RECURRENT_ONLY.items():
                if getattr(self, name):
                    _fail(f"{name} needs a recurrent variant ({why}), not 'drlavt'")
            if self.reads_standoff:
                _fail("standoff_input / command_gain_input need a recurrent variant (an LSTM input), not 'drlavt'")

    def _check_encoder(self):
        """The conv blocks: one entry per block in channels, kernels, strides and pools (lists stored as tuples)."""
        for name in ("channels", "kernels", "strides", "pools", "drlavt_dense"):
            if not isinstance(getattr(self, name), (tuple, list)):
                _fail(f"{name} must be a tuple, got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(getattr(self, name)))  # lists -> tuples (hashable, jit-static)
        n = len(self.channels)
        if n == 0:
            _fail("channels must name at least one conv block")
        if not (len(self.kernels) == len(self.strides) == len(self.pools) == n):
            _fail(
                f"channels, kernels, strides and pools must have the same length (one entry per conv block), "
                f"got {len(self.channels)}, {len(self.kernels)}, {len(self.strides)}, {len(self.pools)}"
            )
        for name in ("channels", "kernels", "strides", "drlavt_dense"):
            if not all(_is_int(v) and v >= 1 for v in getattr(self, name)):
                _fail(f"{name} must be positive integers, got {getattr(self, name)!r}")
        if not all(k % 2 == 1 or k == s for k, s in zip(self.kernels, self.strides)):
            _fail(
                f"kernels must be odd (padding k//2 keeps the grid centred) or equal to their block's stride (a "
                f"patch layer), got kernels {self.kernels!r} with strides {self.strides!r}"
            )

    def _check_state_input(self):
        """The diagnostic true-state input: its gain and entries need state_input (entries stored as ints)."""
        g = self.state_input_gain
        if not _is_number(g) or not (np.isfinite(g) and g > 0):
            _fail(f"state_input_gain must be a finite number > 0, got {g!r}")
        if g != 1.0 and not self.state_input:
            _fail("state_input_gain scales the true state at the input: it needs state_input=True")
        entries = self.state_input_entries
        if not (
            isinstance(entries, (tuple, list))
            and entries
            and len(set(entries)) == len(entries)
            and all(_is_int(i) and 0 <= i < TRUE_STATE_SIZE for i in entries)
        ):
            _fail(f"state_input_entries must be distinct indices in 0-{TRUE_STATE_SIZE - 1}, got {entries!r}")
        entries = tuple(int(i) for i in entries)  # hashable and JSON-friendly
        object.__setattr__(self, "state_input_entries", entries)
        if set(entries) != set(range(TRUE_STATE_SIZE)) and not self.state_input:
            _fail("state_input_entries picks entries of the true state at the input: it needs state_input=True")
        if self.state_input_point not in STATE_INPUT_POINTS:
            _fail(f"state_input_point={self.state_input_point!r} is not one of {STATE_INPUT_POINTS}")
        if self.state_input_point != "centre" and not self.state_input:
            _fail("state_input_point chooses the point of the state at the input: it needs state_input=True")
        if self.state_input_point == "image" and not set(entries) <= {0, 1, 2}:
            _fail(f"state_input_point 'image' reads the error only: state_input_entries among 0-2, got {entries!r}")

    # Derived switches (not fields: nothing is written back into the config).
    @property
    def use_se(self) -> bool:
        return self.variant in ("ramavt", "se")

    @property
    def use_mha(self) -> bool:
        return self.variant in ("ramavt", "mha")

    @property
    def rescales_depth(self) -> bool:
        return self.depth_centre != 0 or self.depth_gain != 1

    @property
    def recurrent(self) -> bool:
        return self.variant != "drlavt"

    @property
    def state_input_mask(self) -> np.ndarray:
        """[TRUE_STATE_SIZE] float32: 1 for the true-state entries the network reads (state_input_entries), else 0."""
        return np.isin(np.arange(TRUE_STATE_SIZE), self.state_input_entries).astype(np.float32)

    @property
    def reads_standoff(self) -> bool:
        """Whether the network takes a per-step stand-off signal (its ``standoff`` argument): k or the command gain."""
        return self.standoff_input or self.command_gain_input

    @property
    def jnp_dtype(self):
        return DTYPES[self.dtype]

    def feature_map_shape(self, height: int, width: int) -> tuple[int, int, int]:
        """Spatial size and channels of the backbone's output for an input of height x width."""
        for k, s, p in zip(self.kernels, self.strides, self.pools):
            height, width = conv_out_size(height, k, s), conv_out_size(width, k, s)
            if p:
                height, width = -(-height // 2), -(-width // 2)
        return height, width, self.channels[-1]
