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
AUX_OUTPUTS = (0, 3, 6)  # NetworkConfig.aux_outputs: none, the tracking error, the error and the relative velocity

# Switches that only a recurrent variant has, with why ('drlavt' stacks frames into one conv input and has no LSTM).
_RECURRENT_ONLY = {
    "aux_outputs": "the head reads the LSTM output",
    "prev_action": "the previous action is an LSTM input",
}


def _fail(msg: str):
    raise ValueError(f"NetworkConfig: {msg}")


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


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
    prev_action: bool = False  # R2D2's LSTM input: the previous action (one-hot; a 'none' entry at episode starts)
    # A linear head of this many outputs on the LSTM output, sown as intermediates 'aux' (apply with
    # mutable=["intermediates"]): the trainer fits it to the true tracking error (3), and with 6 also to the relative
    # velocity (LearnerConfig.aux_weight; imitation.true_tracking_state). 0 = none.
    aux_outputs: int = 0

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
        if self.aux_outputs not in AUX_OUTPUTS or isinstance(self.aux_outputs, bool):
            _fail(f"aux_outputs must be one of {AUX_OUTPUTS}, got {self.aux_outputs!r}")
        if not self.recurrent:
            for name, why in _RECURRENT_ONLY.items():
                if getattr(self, name):
                    _fail(f"{name} needs a recurrent variant ({why}), not 'drlavt'")

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

    # Derived switches (not fields: nothing is written back into the config).
    @property
    def use_se(self) -> bool:
        return self.variant in ("ramavt", "se")

    @property
    def use_mha(self) -> bool:
        return self.variant in ("ramavt", "mha")

    @property
    def recurrent(self) -> bool:
        return self.variant != "drlavt"

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
