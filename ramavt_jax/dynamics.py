"""Target dynamics: Clohessy-Wiltshire relative translation and torque-free rigid-body attitude.

Pure JAX, float32-friendly, jit- and vmap-able. Every function works on a *single* env (unbatched
shapes are given in the docstrings); batch with ``jax.vmap`` in the caller.

Conventions
-----------
* Hill (LVLH) frame of a circular reference orbit: x radial (outward), y along-track (direction of
  motion), z cross-track (orbit normal). CW equations::

      x'' =  3 n^2 x + 2 n y' + a_x
      y'' =         - 2 n x' + a_y
      z'' =   -n^2 z         + a_z

* Quaternions are scalar first ``(w, x, y, z)``. In :func:`attitude_step` the quaternion is
  ``world_from_body`` (it maps body-frame vectors to the world frame, ``v_w = R(q) v_b``) and the
  angular velocity is expressed in the BODY frame, so ``q' = 0.5 q (x) (0, omega)``. This matches
  MuJoCo's free joint (``qpos[3:7]`` world_from_body, ``qvel[3:6]`` local angular velocity).

Performance: tiny matmuls are slow in XLA on CPU (measured in ``benchmarks/bench_env.py``), so everything is
written as explicit scalar multiply-adds on vector components; under ``vmap`` these become
elementwise ops over the batch. The quaternion helpers live in :mod:`ramavt_jax.rotations`.

Float32 notes: at LEO with dt = 0.1 s, n*dt ~ 1e-4, so 1 - cos(n dt) ~ 6e-9 is below float32
epsilon relative to 1. The CW step is therefore written as ``state + increment`` with every
coefficient of the increment computed in a cancellation-free form (sinc, 2 sin^2(x/2), and a
series for (x - sin x) / x^3), so no orbital-coupling term is rounded away.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from ramavt_jax.rotations import mat_to_quat, quat_mul, quat_normalize, quat_to_mat, random_quaternion

__all__ = [
    "MU_EARTH",
    "R_EARTH",
    "mean_motion",
    "cw_step",
    "cw_stm",
    "kinematic_step",
    "quat_mul",
    "quat_to_mat",
    "quat_normalize",
    "mat_to_quat",
    "random_quaternion",
    "attitude_step",
]

MU_EARTH = 3.986004418e14  # m^3 / s^2 (EGM96 / WGS-84 GM)
R_EARTH = 6378137.0  # m (WGS-84 equatorial radius)


# --------------------------------------------------------------------------------------------------
# Orbit
# --------------------------------------------------------------------------------------------------


def mean_motion(altitude_m=400e3):
    """Mean motion ``n = sqrt(mu / a^3)`` [rad/s] of a circular orbit, ``a = R_EARTH + altitude_m``.

    Args:
      altitude_m: scalar altitude above the equatorial radius [m]; python number or (traced) array.

    Returns:
      python float for python input (400 km -> ~1.1313e-3 rad/s), else a scalar array.
    """
    if isinstance(altitude_m, (int, float)):
        return math.sqrt(MU_EARTH / (R_EARTH + altitude_m) ** 3)
    a = R_EARTH + jnp.asarray(altitude_m)
    # mu / a^3 computed as (mu / a) / a / a to stay well inside float32 range.
    return jnp.sqrt(MU_EARTH / a / a / a)


def _sinc(x):
    """sin(x) / x (unnormalised), exact 1 at x = 0, NaN-free gradients."""
    small = jnp.abs(x) < 1e-3
    xs = jnp.where(small, jnp.ones_like(x), x)
    x2 = x * x
    return jnp.where(small, 1.0 - x2 * (1.0 / 6.0) * (1.0 - x2 * (1.0 / 20.0)), jnp.sin(xs) / xs)


# (x - sin x) / x^3 = sum_{k>=1} (-1)^(k+1) x^(2k-2) / (2k+1)!  (Horner in x^2, k = 1..7).
_F3_COEFFS = tuple((-1) ** (k + 1) / math.factorial(2 * k + 1) for k in range(1, 8))


def _f3(x):
    """(x - sin x) / x^3, cancellation-free: series for |x| < 1 (truncation < 3e-15), direct else."""
    x2 = x * x
    series = jnp.zeros_like(x)
    for c in reversed(_F3_COEFFS):
        series = series * x2 + c
    small = jnp.abs(x) < 1.0
    xs = jnp.where(small, jnp.ones_like(x), x)
    direct = (xs - jnp.sin(xs)) / (xs * xs * xs)
    return jnp.where(small, series, direct)


def _cw_coeffs(n, dt, dtype):
    """Cancellation-free scalar coefficients of the CW transition over ``dt``.

    Returns (with th = n dt, s = sin th, c = cos th):
      omc = 1 - c, s, S = s / n, Q = (1 - c) / n^2, F = (th - s) / n^3, n, t  -- all finite at n = 0.
    """
    n = jnp.asarray(n, dtype)
    t = jnp.asarray(dt, dtype)
    th = n * t
    sh = jnp.sin(0.5 * th)
    omc = 2.0 * sh * sh
    s = jnp.sin(th)
    S = t * _sinc(th)
    sinc_h = _sinc(0.5 * th)
    Q = 0.5 * t * t * sinc_h * sinc_h
    F = t * t * t * _f3(th)
    return omc, s, S, Q, F, n, t


def cw_step(pos, vel, accel, n, dt):
    """Exact Clohessy-Wiltshire transition over ``dt`` with a constant acceleration.

    Closed form (homogeneous part = the standard CW state-transition matrix, forced part =
    int_0^dt Phi_{., v}(sigma) d sigma @ accel, exact for a constant acceleration in the Hill frame):

      x  = x0 + 3(1-c) x0 + (s/n) vx + 2(1-c)/n vy + (1-c)/n^2 ax + 2(th-s)/n^2 ay
      y  = y0 + 6(s-th) x0 - 2(1-c)/n vx + (4s/n - 3t) vy - 2(th-s)/n^2 ax + (4(1-c)/n^2 - 1.5t^2) ay
      z  = c z0 + (s/n) vz + (1-c)/n^2 az
      vx = 3 n s x0 + c vx + 2 s vy + (s/n) ax + 2(1-c)/n ay
      vy = -6 n (1-c) x0 - 2 s vx + (4c - 3) vy - 2(1-c)/n ax + (4s/n - 3t) ay
      vz = -n s z0 + c vz + (s/n) az

    with th = n dt, s = sin th, c = cos th; evaluated as ``state + increment`` with
    cancellation-free coefficients (accurate in float32 for tiny n dt, and reduces exactly to
    constant-acceleration kinematics at n = 0).

    Args:
      pos: [3] relative position in the Hill frame [m].
      vel: [3] relative velocity in the Hill frame [m/s].
      accel: [3] constant acceleration in the Hill frame over the step [m/s^2].
      n: scalar mean motion [rad/s] (python float or traced).
      dt: scalar step [s] (python float or traced).

    Returns:
      (pos [3], vel [3]) after ``dt``, dtype of ``pos``/``vel``/``accel``.
    """
    pos = jnp.asarray(pos)
    vel = jnp.asarray(vel)
    accel = jnp.asarray(accel)
    dtype = jnp.result_type(pos, vel, accel)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    omc, s, S, Q, F, n, t = _cw_coeffs(n, dt, dtype)
    x, y, z = pos[0], pos[1], pos[2]
    vx, vy, vz = vel[0], vel[1], vel[2]
    ax, ay, az = accel[0], accel[1], accel[2]

    nQ2 = 2.0 * n * Q  # 2 (1 - c) / n
    nF2 = 2.0 * n * F  # 2 (th - s) / n^2
    n2F4 = 4.0 * n * n * F  # 4 (th - s) / n   (t - n2F4 = 4 s / n - 3 t)
    n3F6 = 6.0 * n * n * n * F  # 6 (th - s)

    dx = 3.0 * omc * x + S * vx + nQ2 * vy + Q * ax + nF2 * ay
    dy = -n3F6 * x - nQ2 * vx - n2F4 * vy + t * vy - nF2 * ax + (4.0 * Q - 1.5 * t * t) * ay
    dz = -omc * z + S * vz + Q * az
    dvx = 3.0 * n * s * x - omc * vx + 2.0 * s * vy + S * ax + nQ2 * ay
    dvy = -6.0 * n * omc * x - 2.0 * s * vx - 4.0 * omc * vy - nQ2 * ax + (t - n2F4) * ay
    dvz = -n * s * z - omc * vz + S * az

    new_pos = jnp.stack([x + dx, y + dy, z + dz]).astype(dtype)
    new_vel = jnp.stack([vx + dvx, vy + dvy, vz + dvz]).astype(dtype)
    return new_pos, new_vel


def cw_stm(n, dt):
    """Homogeneous CW state-transition matrix ``Phi(dt)`` for the state ``(x, y, z, vx, vy, vz)``.

    ``[pos; vel](dt) = Phi @ [pos; vel](0)`` when ``accel = 0``. Reference / test helper; the
    environment should use :func:`cw_step` (explicit multiply-adds are much faster on CPU).

    Args:
      n: scalar mean motion [rad/s]; dt: scalar time [s].

    Returns:
      [6, 6] array (float dtype of ``n``/``dt``, float32 unless x64 is enabled).
    """
    dtype = jnp.result_type(jnp.asarray(n), jnp.asarray(dt), float)
    omc, s, S, Q, F, n, t = _cw_coeffs(n, dt, dtype)
    c = 1.0 - omc
    z = jnp.zeros_like(t)
    o = jnp.ones_like(t)
    rows = [
        [1.0 + 3.0 * omc, z, z, S, 2.0 * n * Q, z],
        [-6.0 * n * n * n * F, o, z, -2.0 * n * Q, t - 4.0 * n * n * F, z],
        [z, z, c, z, z, S],
        [3.0 * n * s, z, z, c, 2.0 * s, z],
        [-6.0 * n * omc, z, z, -2.0 * s, 1.0 - 4.0 * omc, z],
        [z, z, -n * s, z, z, c],
    ]
    return jnp.stack([jnp.stack([jnp.asarray(e, dtype) for e in r]) for r in rows])


def kinematic_step(pos, vel, dt):
    """Original benchmark mode: constant velocity, no orbital coupling.

    Args:
      pos: [3] position [m]; vel: [3] velocity [m/s]; dt: scalar step [s].

    Returns:
      (pos + vel * dt [3], vel [3]).
    """
    pos = jnp.asarray(pos)
    vel = jnp.asarray(vel)
    return pos + vel * dt, vel


# --------------------------------------------------------------------------------------------------
# Torque-free rigid body attitude
# --------------------------------------------------------------------------------------------------


def _euler_coeffs(inertia):
    """k = ((I2 - I3)/I1, (I3 - I1)/I2, (I1 - I2)/I3), 0 where I_i = 0, clipped to [-1, 1].

    For any physical inertia (triangle inequality |I_j - I_k| <= I_i) |k_i| <= 1, so the clip is a
    no-op there; it keeps non-physical or degenerate inputs (tiny/zero moments) non-stiff. A sphere
    gives k = 0 exactly (constant omega), and I_i = 0 freezes omega_i (I_i omega_i' = 0).
    """
    i1, i2, i3 = inertia[0], inertia[1], inertia[2]

    def safe_div(a, b):
        ok = b != 0.0
        return jnp.where(ok, a / jnp.where(ok, b, jnp.ones_like(b)), jnp.zeros_like(a))

    k = jnp.stack([safe_div(i2 - i3, i1), safe_div(i3 - i1, i2), safe_div(i1 - i2, i3)])
    return jnp.clip(k, -1.0, 1.0)


def _attitude_rhs(q, w, k):
    """Time derivative of the torque-free body state, on component tuples.

    q = (qw, qx, qy, qz), w = (wx, wy, wz), k from _euler_coeffs -> (dq tuple, dw tuple).
    Components are kept as separate scalars (no stacking) so that, under vmap, XLA sees flat
    elementwise ops on [B] vectors instead of strided slices / concatenates of [B, 4] arrays.
    """
    qw, qx, qy, qz = q
    wx, wy, wz = w
    # q' = 0.5 * q (x) (0, w)
    dq = (
        -0.5 * (qx * wx + qy * wy + qz * wz),
        0.5 * (qw * wx + qy * wz - qz * wy),
        0.5 * (qw * wy - qx * wz + qz * wx),
        0.5 * (qw * wz + qx * wy - qy * wx),
    )
    # Euler: I1 w1' = (I2 - I3) w2 w3, cyclic.
    dw = (k[0] * wy * wz, k[1] * wz * wx, k[2] * wx * wy)
    return dq, dw


def attitude_step(quat, omega, inertia, dt, substeps: int = 4):
    """Torque-free rigid-body attitude over ``dt`` (Euler's equations + quaternion kinematics).

    ``I omega' = (I omega) x omega`` in the body frame (principal axes, diagonal inertia) and
    ``q' = 0.5 q (x) (0, omega)`` with ``q`` = world_from_body. Integrated with ``substeps`` classical
    RK4 substeps on the joint 7-D state (4th order in both attitude and rate; with dt = 0.1 s,
    4 substeps and |omega| < 1 rad/s the truncation error is ~1e-10 per step, far below float32
    round-off), renormalising the quaternion after every substep. Measured in float32 over 1000
    steps (100 s, spins up to 0.5 rad/s per axis): world angular momentum and kinetic energy drift
    ~2e-6..5e-6 relative, orientation within ~1e-4 rad of MuJoCo's RK4 free body (tests).

    Args:
      quat: [4] world_from_body unit quaternion, scalar first.
      omega: [3] angular velocity in the BODY frame [rad/s].
      inertia: [3] principal moments of inertia (any common scale). Degenerate cases are safe: equal
        moments give constant omega exactly; zero moments give zero coupling (see _euler_coeffs).
      dt: scalar step [s] (python float or traced).
      substeps: static number of RK4 substeps (python int >= 1).

    Returns:
      (quat [4] unit, omega [3]) after ``dt``.
    """
    quat = jnp.asarray(quat)
    omega = jnp.asarray(omega)
    dtype = jnp.result_type(quat, omega)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    quat = quat.astype(dtype)
    omega = omega.astype(dtype)
    k = _euler_coeffs(jnp.asarray(inertia, dtype))
    k = (k[0], k[1], k[2])
    h = jnp.asarray(dt, dtype) / substeps

    def axpy(a, x, y):  # y + a * x on component tuples
        return tuple(yi + a * xi for xi, yi in zip(x, y))

    def rk4(q, w):
        k1q, k1w = _attitude_rhs(q, w, k)
        k2q, k2w = _attitude_rhs(axpy(0.5 * h, k1q, q), axpy(0.5 * h, k1w, w), k)
        k3q, k3w = _attitude_rhs(axpy(0.5 * h, k2q, q), axpy(0.5 * h, k2w, w), k)
        k4q, k4w = _attitude_rhs(axpy(h, k3q, q), axpy(h, k3w, w), k)
        h6 = h / 6.0
        q = tuple(qi + h6 * (a + 2.0 * b + 2.0 * c + d) for qi, a, b, c, d in zip(q, k1q, k2q, k3q, k4q))
        w = tuple(wi + h6 * (a + 2.0 * b + 2.0 * c + d) for wi, a, b, c, d in zip(w, k1w, k2w, k3w, k4w))
        # renormalise (|q| stays ~1 to within h^5, so no zero-norm guard is needed here)
        inv = jax.lax.rsqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        return tuple(qi * inv for qi in q), w

    q0 = quat_normalize(quat)
    q = (q0[0], q0[1], q0[2], q0[3])
    w = (omega[0], omega[1], omega[2])
    # Substeps as a rolled loop: an unrolled 4-substep RK4 chain runs ~100x slower when the caller
    # puts attitude_step inside lax.scan on XLA:CPU (measured); one substep per iteration is fast.
    q, w = jax.lax.fori_loop(0, int(substeps), lambda _, c: rk4(*c), (q, w))
    return jnp.stack(q), jnp.stack(w)
