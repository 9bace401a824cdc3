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
    pool_first: bool = True  # conv -> pool -> SE -> norm -> ReLU (fast); False: *orig* conv -> SE -> norm -> pool -> ReLU
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
    # preset it lost, docs/experiments.md arm dense-norm). Recurrent variants only.
    dense_norm: bool = False
    # A diagnostic, not a tracker: the true tracking error and relative velocity (TRUE_STATE_SIZE numbers in
    # stand-off distances, greedy.true_tracking_state) beside the encoder's features at the LSTM's input, read from
    # the simulator at every step (the caller passes true_state [B, T, 6]). Trained so, the agent measures how far
    # this learner gets with perfect perception at a budget: the part of the gap to the ceiling that is not in the
    # images. Recurrent variants only.
    state_input: bool = False
    # The true state times this at the LSTM's input (state_input only). In stand-off distances a 0.05 m error reads
    # 0.01 beside features of order 1: a gain asks whether the diagnostic's shortfall is the learner's or the scale's.
    state_input_gain: float = 1.0
    # Which of the TRUE_STATE_SIZE entries the network reads (state_input only; the others read 0): 0-2 the error
    # across the image (x, y) and along the boresight (z), 3-5 the relative velocity likewise. A subset asks which
    # part of the state the images fail to give.
    state_input_entries: tuple[int, ...] = tuple(range(TRUE_STATE_SIZE))
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
        def fail(msg):
            raise ValueError(f"NetworkConfig: {msg}")

        if self.variant not in VARIANTS:
            fail(f"variant={self.variant!r} is not one of {VARIANTS}")
        if self.norm not in NORMS:
            fail(f"norm={self.norm!r} is not one of {NORMS}")
        if self.conv_impl not in CONV_IMPLS:
            fail(f"conv_impl={self.conv_impl!r} is not one of {CONV_IMPLS}")
        if self.dtype not in DTYPES:
            fail(f"dtype={self.dtype!r} is not one of {tuple(DTYPES)}")
        for name in ("channels", "kernels", "strides", "pools", "drlavt_dense"):
            if not isinstance(getattr(self, name), (tuple, list)):
                fail(f"{name} must be a tuple, got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(getattr(self, name)))  # lists -> tuples (hashable, jit-static)
        n = len(self.channels)
        if n == 0:
            fail("channels must name at least one conv block")
        if not (len(self.kernels) == len(self.strides) == len(self.pools) == n):
            fail(
                f"channels, kernels, strides and pools must have the same length (one entry per conv block), "
                f"got {len(self.channels)}, {len(self.kernels)}, {len(self.strides)}, {len(self.pools)}"
            )
        for name in ("channels", "kernels", "strides", "drlavt_dense"):
            vals = getattr(self, name)
            if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1 for v in vals):
                fail(f"{name} must be positive integers, got {vals!r}")
        if not all(k % 2 == 1 or k == s for k, s in zip(self.kernels, self.strides)):
            fail(f"kernels must be odd (padding k//2 keeps the grid centred) or equal to their block's stride (a "
                 f"patch layer), got kernels {self.kernels!r} with strides {self.strides!r}")
        for name in ("num_actions", "se_reduction", "attention_heads", "dense", "lstm", "lstm_layers", "head",
                     "frame_stack"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                fail(f"{name} must be a positive integer, got {v!r}")
        if not isinstance(self.aux_outputs, (int, np.integer)) or self.aux_outputs < 0:
            fail(f"aux_outputs must be an integer >= 0, got {self.aux_outputs!r}")
        if self.aux_outputs and not self.recurrent:
            fail("aux_outputs needs a recurrent variant (the head reads the LSTM output), not 'drlavt'")
        for name in ("depth_centre", "depth_gain"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating, np.integer)) or isinstance(v, bool) or not np.isfinite(v):
                fail(f"{name} must be a finite number, got {v!r}")
        if not self.depth_gain > 0:
            fail(f"depth_gain must be > 0 (1 = the observation as it is), got {self.depth_gain!r}")
        if self.rescales_depth and not self.coord_channels:
            fail("depth_centre / depth_gain need coord_channels=True: once centred, a target pixel at depth_centre "
                 "reads 0 like the background, and only the hit mask tells them apart")
        if self.silhouette_stats and not self.recurrent:
            fail("silhouette_stats needs a recurrent variant (one frame per encoder input), not 'drlavt', whose "
                 "encoder sees a stack of frames")
        if self.dense_norm and not self.recurrent:
            fail("dense_norm needs a recurrent variant (it normalises the dense layer and head around the LSTM), not "
                 "'drlavt'")
        if self.prev_action and not self.recurrent:
            fail("prev_action needs a recurrent variant (the previous action is an LSTM input), not 'drlavt'")
        if isinstance(self.quantiles, bool) or not isinstance(self.quantiles, (int, np.integer)) or (
                self.quantiles == 1 or self.quantiles < 0):
            fail(f"quantiles must be 0 (expected values) or an integer >= 2, got {self.quantiles!r}")
        if self.policy_head and (self.quantiles or not self.recurrent):
            fail("policy_head needs a recurrent variant (the head reads the LSTM output) and no quantiles")
        if self.quantiles and self.dueling:
            fail("quantiles and dueling are not combined (a dueling head of quantiles is not defined here)")
        if self.standoff_input and self.command_gain_input:
            fail("standoff_input and command_gain_input are two forms of one input: choose one")
        if self.reads_standoff and not self.recurrent:
            fail("standoff_input / command_gain_input need a recurrent variant (an LSTM input), not 'drlavt'")
        if self.state_input and not self.recurrent:
            fail("state_input needs a recurrent variant (an LSTM input), not 'drlavt'")
        g = self.state_input_gain
        if isinstance(g, bool) or not isinstance(g, (int, float, np.floating, np.integer)) or not (
                np.isfinite(g) and g > 0):
            fail(f"state_input_gain must be a finite number > 0, got {g!r}")
        if g != 1.0 and not self.state_input:
            fail("state_input_gain scales the true state at the input: it needs state_input=True")
        entries = self.state_input_entries
        if not (isinstance(entries, (tuple, list)) and entries and len(set(entries)) == len(entries) and all(
                isinstance(i, (int, np.integer)) and not isinstance(i, bool) and 0 <= i < TRUE_STATE_SIZE
                for i in entries)):
            fail(f"state_input_entries must be distinct indices in 0-{TRUE_STATE_SIZE - 1}, got {entries!r}")
        entries = tuple(int(i) for i in entries)  # hashable and JSON-friendly
        object.__setattr__(self, "state_input_entries", entries)
        if set(entries) != set(range(TRUE_STATE_SIZE)) and not self.state_input:
            fail("state_input_entries picks entries of the true state at the input: it needs state_input=True")
        r = self.exposure_rate
        if isinstance(r, bool) or not isinstance(r, (int, float, np.floating, np.integer)) or not 0 <= r <= 1:
            fail(f"exposure_rate must be a number in [0, 1] (0: off), got {r!r}")
        if r and not self.recurrent:
            fail("exposure_rate needs a recurrent variant (its average rides in the recurrent state), not 'drlavt'")
        if self.frame_difference and not self.recurrent:
            fail("frame_difference needs a recurrent variant, not 'drlavt' (which stacks whole frames: frame_stack)")
        if self.use_mha and self.channels[-1] % self.attention_heads != 0:
            fail(
                f"attention_heads={self.attention_heads} must divide the last block's channels "
                f"({self.channels[-1]}) for variant {self.variant!r}"
            )

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
