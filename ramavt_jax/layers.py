"""Building blocks of the RAMAVT Q-network (flax.linen).

Everything here is shape-agnostic in the spatial size so one set of parameters works for any resolution
with the same channel count. Layout is NHWC throughout.

Speed notes (2-core CPU, measured with ``benchmarks/bench_network.py`` and ``lab/benchmarks/bench_conv.py``):
- The im2col conv (pad + k*k strided slices + one matmul) is much faster than XLA's convolution on CPU in the
  backward pass, XLA's about twice as fast in a forward pass alone: ``conv2d_hybrid`` (the default) takes each
  one's fast pass. Every implementation stores its kernel exactly like ``flax.linen.Conv`` (``kernel``,
  ``[k, k, C_in, C_out]``), so they share parameter trees.
- ``max_pool2`` is a reshape + max (ceil mode), not ``reduce_window``: its gradient is a cheap mask instead
  of XLA's ``select_and_scatter``.
- ``LSTMStack`` hoists the first layer's input projection out of the time scan (one big matmul over all
  B*T frames); only the recurrent matmuls (and the deeper layers' input projections) run inside the scan.
"""

from __future__ import annotations

import functools
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax import lax

Array = jax.Array
Dtype = Any

# ReLU nets: He (fan-in, variance 2) init for conv / hidden dense kernels. Plain normals: truncated normals
# compile noticeably slower on CPU (erfinv) and initialisation time dominated the tests.
he_init = nn.initializers.variance_scaling(2.0, "fan_in", "normal")
lecun_init = nn.initializers.variance_scaling(1.0, "fan_in", "normal")


def conv_out_size(size: int, kernel: int, stride: int) -> int:
    """Output size of a block's conv: symmetric padding ``kernel // 2`` (PyTorch ``padding=k//2``), or, for a patch
    layer (kernel == stride), ``ceil(size / kernel)`` non-overlapping patches."""
    if kernel == stride:
        return -(-size // kernel)
    pad = kernel // 2
    return (size + 2 * pad - kernel) // stride + 1


def conv2d_patches(x: Array, kernel: Array, stride: int | None = None) -> Array:
    """A patch layer: a conv whose kernel equals its stride, as space-to-depth + one matmul (no padding, no
    overlapping patches, so no im2col copy: the input is only transposed).

    x: [N, H, W, C]; kernel: [k, k, C, F] (flax layout). H and W are zero-padded at the end to multiples of k.
    Returns [N, ceil(H / k), ceil(W / k), F]; equal to ``lax.conv_general_dilated`` with stride k and that padding.
    """
    n, h, w, c = x.shape
    k = kernel.shape[0]
    if stride is not None and stride != k:
        raise ValueError(f"conv2d_patches: a patch layer's stride equals its kernel size, got {stride} and {k}")
    ho, wo = -(-h // k), -(-w // k)
    if ho * k != h or wo * k != w:
        x = jnp.pad(x, ((0, 0), (0, ho * k - h), (0, wo * k - w), (0, 0)))
    patches = x.reshape(n, ho, k, wo, k, c).transpose(0, 1, 3, 2, 4, 5)  # [N, Ho, Wo, k, k, C]: kernel order
    out = patches.reshape(n * ho * wo, k * k * c) @ kernel.reshape(k * k * c, -1)
    return out.reshape(n, ho, wo, -1)


def conv2d_im2col(x: Array, kernel: Array, stride: int) -> Array:
    """2-D convolution as pad + k*k strided slices + one matmul.

    x: [N, H, W, C]; kernel: [k, k, C, F] (flax layout); padding k//2 on every side.
    Returns [N, H_out, W_out, F]. Numerically the same as ``lax.conv_general_dilated`` with that padding.
    """
    n, h, w, c = x.shape
    k = kernel.shape[0]
    pad = k // 2
    ho, wo = conv_out_size(h, k, stride), conv_out_size(w, k, stride)
    if pad:
        x = jnp.pad(x, ((0, 0), (pad, pad), (pad, pad), (0, 0)))
    if k == 1:
        patches = x[:, : stride * (ho - 1) + 1 : stride, : stride * (wo - 1) + 1 : stride, :]
    else:
        cols = [
            lax.slice(
                x,
                (0, i, j, 0),
                (n, i + stride * (ho - 1) + 1, j + stride * (wo - 1) + 1, c),
                (1, stride, stride, 1),
            )
            for i in range(k)
            for j in range(k)
        ]
        patches = jnp.concatenate(cols, axis=-1)  # [N, Ho, Wo, k*k*C], (i, j, c) order = kernel row-major
    out = patches.reshape(n * ho * wo, k * k * c) @ kernel.reshape(k * k * c, -1)
    return out.reshape(n, ho, wo, -1)


def conv2d_lax(x: Array, kernel: Array, stride: int) -> Array:
    """XLA's convolution with padding k//2: x [N, H, W, C], kernel [k, k, C, F] -> [N, H_out, W_out, F]. On this CPU
    its forward is about twice the im2col forward, its backward slower than im2col's (benchmarks/RESULTS.md)."""
    pad = kernel.shape[0] // 2
    return lax.conv_general_dilated(
        x, kernel, (stride, stride), ((pad, pad), (pad, pad)), dimension_numbers=("NHWC", "HWIO", "NHWC")
    )


# Below this many input channels the im2col forward beats XLA's (2 channels, 32x32, stride 2: 14 vs 19 ms per 1,312
# frames; 16 and 32 channels: XLA's is 2x faster; benchmarks/RESULTS.md).
HYBRID_MIN_CHANNELS = 8


def conv2d_hybrid(x: Array, kernel: Array, stride: int) -> Array:
    """The fast conv of each pass, with the shapes and parameters of ``conv2d_im2col``. With at least
    ``HYBRID_MIN_CHANNELS`` input channels: XLA's convolution where no gradient is taken (acting, the target net, the
    burn-in), the im2col conv under a gradient (its forward builds the patches that its backward reuses, and its
    backward is the faster one). With fewer: the im2col conv throughout."""
    if x.shape[-1] < HYBRID_MIN_CHANNELS:
        return conv2d_im2col(x, kernel, stride)
    return _lax_forward_im2col_gradient(x, kernel, stride)


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _lax_forward_im2col_gradient(x: Array, kernel: Array, stride: int) -> Array:
    return _lax_conv_per_kernel(stride)(x, kernel)


@functools.cache
def _lax_conv_per_kernel(stride: int):
    """``conv2d_lax`` at ``stride`` whose vmap keeps one convolution per kernel. vmapped over kernels (the seeds of a
    ``--seeds N`` program), XLA's convolution becomes a grouped convolution that runs about 4x slower on this CPU
    than the separate ones; so on CPU batched kernels are looped over (other backends keep the grouped convolution),
    and a batch of inputs alone joins the frame axis. Forward only (it serves the primal of the hybrid conv, whose
    gradient is the im2col conv's)."""

    @jax.custom_batching.custom_vmap
    def conv(x: Array, kernel: Array) -> Array:
        return conv2d_lax(x, kernel, stride)

    @conv.def_vmap
    def _batched(axis_size: int, in_batched: list, x: Array, kernel: Array):
        x_batched, kernel_batched = in_batched
        if not kernel_batched:  # [S, N, ...] -> [S * N, ...]
            out = conv(x.reshape(-1, *x.shape[2:]), kernel)
            return out.reshape(axis_size, -1, *out.shape[1:]), True
        if jax.default_backend() != "cpu":  # the grouped convolution is slow on CPU; unmeasured elsewhere: XLA's rule
            grouped = jax.vmap(functools.partial(conv2d_lax, stride=stride), (0 if x_batched else None, 0))
            return grouped(x, kernel), True
        if not x_batched:
            x = jnp.broadcast_to(x, (axis_size, *x.shape))
        if axis_size <= 8:  # unrolled (one scratch run, 3 seeds: 52 ms, lax.map 59 ms); the loop bounds program size
            return jnp.stack([conv(x[i], kernel[i]) for i in range(axis_size)]), True
        return lax.map(lambda xk: conv(*xk), (x, kernel)), True

    return conv


def _hybrid_fwd(x: Array, kernel: Array, stride: int):
    return jax.vjp(functools.partial(conv2d_im2col, stride=stride), x, kernel)  # (output, pullback as residual)


def _hybrid_bwd(stride: int, pullback, cotangent: Array):
    return pullback(cotangent)


_lax_forward_im2col_gradient.defvjp(_hybrid_fwd, _hybrid_bwd)
CONV_FUNCTIONS = {"im2col": conv2d_im2col, "lax": conv2d_lax, "hybrid": conv2d_hybrid}


class PaddedConv(nn.Module):
    """Bias-free conv with padding k//2 (PyTorch ``padding=k//2``), or a patch layer where the kernel size equals
    the stride (``conv2d_patches``, whatever ``impl``). Every ``impl`` of ``CONV_FUNCTIONS`` stores the kernel like
    ``flax.linen.Conv(use_bias=False)`` (``kernel``, ``[k, k, C_in, C_out]``), so they share parameter trees and
    checkpoints."""

    features: int
    kernel_size: int
    stride: int = 1
    impl: str = "hybrid"
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: Array, planes: Array | None = None) -> Array:
        """x [N, H, W, C] -> [N, H_out, W_out, F]. ``planes`` [H, W, P]: input channels that are the same in every
        frame (pixel coordinates), appended after x's: the kernel sees C + P channels, but the planes' share of the
        output is computed once, on one frame, and added to every frame's (the patches are then built from C
        channels only)."""
        k, c = self.kernel_size, x.shape[-1]
        p = 0 if planes is None else planes.shape[-1]
        kernel = self.param("kernel", he_init, (k, k, c + p, self.features), jnp.float32).astype(self.dtype)
        conv = conv2d_patches if k == self.stride > 1 else CONV_FUNCTIONS[self.impl]
        out = conv(x.astype(self.dtype), kernel[:, :, :c], self.stride)
        if p:
            out = out + conv(planes[None].astype(self.dtype), kernel[:, :, c:], self.stride)
        return out


def make_conv(features: int, kernel: int, stride: int, impl: str, dtype: Dtype, name: str) -> nn.Module:
    """The block's conv, one of ``CONV_FUNCTIONS`` ('hybrid' | 'im2col' | 'lax'); identical parameters."""
    return PaddedConv(features, kernel, stride, impl=impl, dtype=dtype, name=name)


def max_pool2(x: Array) -> Array:
    """2x2 max-pool, stride 2, ceil mode (odd sizes padded with -inf, so 1x1 stays 1x1). x: [N, H, W, C].

    Max of four strided slices: its gradient is a chain of cheap selects (about 2x faster than a reshape+max
    and 4x faster than ``nn.max_pool``'s select_and_scatter on this CPU).
    """
    h, w = x.shape[1], x.shape[2]
    ph, pw = h % 2, w % 2
    if ph or pw:
        x = jnp.pad(x, ((0, 0), (0, ph), (0, pw), (0, 0)), constant_values=-jnp.inf)
    return jnp.maximum(jnp.maximum(x[:, 0::2, 0::2], x[:, 0::2, 1::2]), jnp.maximum(x[:, 1::2, 0::2], x[:, 1::2, 1::2]))


class SqueezeExcite(nn.Module):
    """SE layer: global average pool -> dense C/r -> ReLU -> dense C -> sigmoid -> channel scale."""

    reduction: int = 8
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: Array) -> Array:  # [N, H, W, C]
        c = x.shape[-1]
        s = x.mean(axis=(1, 2))  # [N, C]
        s = nn.relu(nn.Dense(max(1, c // self.reduction), dtype=self.dtype, kernel_init=he_init, name="squeeze")(s))
        s = nn.sigmoid(nn.Dense(c, dtype=self.dtype, kernel_init=lecun_init, name="excite")(s))
        return x * s[:, None, None, :].astype(x.dtype)


class AttentionGate(nn.Module):
    """Multi-head self-attention over the spatial positions as tokens; the output multiplies the features.

    x: [N, h, w, C] -> x * MHA(x) (elementwise gating, as the original). No positional encoding (the flatten that
    follows keeps positions). With a 1x1 feature map (64x64 input with the default backbone) there is a
    single token: the attention weights are 1 and the gate is a learned linear map of the features.
    """

    num_heads: int = 8
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: Array) -> Array:
        n, h, w, c = x.shape
        tokens = x.reshape(n, h * w, c)
        att = nn.MultiHeadDotProductAttention(
            num_heads=self.num_heads, qkv_features=c, out_features=c, dtype=self.dtype, name="mha"
        )(tokens)
        return x * att.reshape(n, h, w, c).astype(x.dtype)


class _LSTMCellStack(nn.Module):
    """One time step of a stacked LSTM whose first-layer input gates were precomputed.

    carry: (h, c), each [L, B, H]; inputs: (gates0 [B, 4H], reset [B] bool). The carry is zeroed where
    ``reset`` (episode start) BEFORE this step's input is consumed. Gate order i, f, g, o.
    """

    features: int
    layers: int
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, carry, inputs):
        h, c = carry
        gates_in, reset = inputs
        keep = jnp.logical_not(reset)[None, :, None]
        h = jnp.where(keep, h, 0.0)
        c = jnp.where(keep, c, 0.0)
        hs, cs = [], []
        for layer in range(self.layers):
            if layer > 0:
                gates_in = nn.Dense(4 * self.features, dtype=self.dtype, kernel_init=lecun_init, name=f"in{layer}")(
                    hs[-1]
                )
            rec = nn.Dense(
                4 * self.features,
                use_bias=False,
                dtype=self.dtype,
                kernel_init=nn.initializers.orthogonal(),
                name=f"rec{layer}",
            )(h[layer])
            gates = (gates_in + rec).astype(jnp.float32)
            i, f, g, o = jnp.split(gates, 4, axis=-1)
            c_new = nn.sigmoid(f) * c[layer] + nn.sigmoid(i) * jnp.tanh(g)
            h_new = nn.sigmoid(o) * jnp.tanh(c_new)
            hs.append(h_new)
            cs.append(c_new)
        return (jnp.stack(hs), jnp.stack(cs)), hs[-1]


class LSTMStack(nn.Module):
    """Stacked LSTM over time with episode resets (purejaxrl ScannedRNN pattern, one ``nn.scan``).

    x: [B, T, D]; reset: [B, T] bool; carry (h, c) each [L, B, H] -> (y [B, T, H], (h, c)).
    """

    features: int
    layers: int
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x: Array, reset: Array, carry):
        # First-layer input projection for all B*T frames at once (one large matmul, outside the scan).
        gates0 = nn.Dense(4 * self.features, dtype=self.dtype, kernel_init=lecun_init, name="in0")(x)
        scan = nn.scan(
            _LSTMCellStack,
            variable_broadcast="params",
            split_rngs={"params": False},
            in_axes=1,
            out_axes=1,
        )
        carry, y = scan(self.features, self.layers, self.dtype, name="cell")(carry, (gates0, reset))
        return y, carry
