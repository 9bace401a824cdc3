"""Quaternion helpers (scalar first: w, x, y, z), single-env shapes, written as scalar multiply-adds (fast under
``vmap`` on CPU, see :mod:`ramavt_jax.dynamics`). ``world_from_body`` quaternions map body vectors to the world."""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["quat_mul", "quat_to_mat", "quat_normalize", "mat_to_quat", "random_quaternion"]


# --------------------------------------------------------------------------------------------------
# Quaternions (scalar first: w, x, y, z)
# --------------------------------------------------------------------------------------------------


def quat_mul(q, r):
    """Hamilton product ``q (x) r`` of scalar-first quaternions. q, r: [4] -> [4].

    With world_from_body quaternions, ``quat_mul(q_a_from_b, q_b_from_c) = q_a_from_c``.
    """
    w1, x1, y1, z1 = q[0], q[1], q[2], q[3]
    w2, x2, y2, z2 = r[0], r[1], r[2], r[3]
    return jnp.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def quat_to_mat(q):
    """Rotation matrix of a unit scalar-first quaternion. q: [4] -> [3, 3] (``v' = R @ v``).

    The quaternion is normalised internally (a zero quaternion gives the identity).
    """
    q = quat_normalize(q)
    w, x, y, z = q[0], q[1], q[2], q[3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return jnp.stack(
        [
            jnp.stack([1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)]),
            jnp.stack([2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)]),
            jnp.stack([2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)]),
        ]
    )


def quat_normalize(q):
    """Unit quaternion ``q / |q|``. q: [4] -> [4]; a zero input gives the identity (1, 0, 0, 0)."""
    q = jnp.asarray(q)
    nrm2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
    ok = nrm2 > 0.0
    inv = jax.lax.rsqrt(jnp.where(ok, nrm2, jnp.ones_like(nrm2)))
    ident = jnp.asarray([1.0, 0.0, 0.0, 0.0], q.dtype)
    return jnp.where(ok, q * inv, ident)


def mat_to_quat(m):
    """Scalar-first unit quaternion of a rotation matrix (Shepperd's method, branch-free).

    Args:
      m: [3, 3] rotation matrix.

    Returns:
      [4] unit quaternion with w >= 0 (canonical sign), ``quat_to_mat(mat_to_quat(m)) == m``.
    """
    m = jnp.asarray(m)
    m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
    m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
    m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
    tr = m00 + m11 + m22
    # Four candidates (each exact up to scale); pick the one with the largest pivot for stability.
    c0 = jnp.stack([1.0 + tr, m21 - m12, m02 - m20, m10 - m01])
    c1 = jnp.stack([m21 - m12, 1.0 + m00 - m11 - m22, m01 + m10, m02 + m20])
    c2 = jnp.stack([m02 - m20, m01 + m10, 1.0 - m00 + m11 - m22, m12 + m21])
    c3 = jnp.stack([m10 - m01, m02 + m20, m12 + m21, 1.0 - m00 - m11 + m22])
    piv = jnp.stack([tr, m00, m11, m22])
    idx = jnp.argmax(piv)
    cands = jnp.stack([c0, c1, c2, c3])
    q = cands[idx]
    q = quat_normalize(q)
    return jnp.where(q[0] < 0.0, -q, q)


def random_quaternion(key):
    """Uniformly distributed (Haar measure on SO(3)) unit quaternion, scalar first.

    Shoemake's subgroup algorithm (three uniforms; no rejection, no near-zero normalisation).

    Args:
      key: a ``jax.random`` key.

    Returns:
      [4] unit quaternion (float32 unless x64 is enabled).
    """
    u1, u2, u3 = jax.random.uniform(key, (3,))
    a = jnp.sqrt(1.0 - u1)
    b = jnp.sqrt(u1)
    t2 = 2.0 * jnp.pi * u2
    t3 = 2.0 * jnp.pi * u3
    return jnp.stack([b * jnp.cos(t3), a * jnp.sin(t2), a * jnp.cos(t2), b * jnp.sin(t3)])
