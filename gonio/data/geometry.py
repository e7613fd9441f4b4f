"""Geometry conventions of the fabric frame, shared by plans, datasets and the instrument.

docs/physics.md section 1: z = fabric normal, x = warp; a direction points AWAY from the surface
(``w_i`` towards the source, ``w_o`` towards the detector) with spherical angles
``w = (sin t cos p, sin t sin p, cos t)``. In-plane curves use the signed observation angle ``s``:
with the source at azimuth ``phi_i``, ``s >= 0`` (mirror side) means ``phi_o = phi_i + 180`` and
``s < 0`` (source side) ``phi_o = phi_i``; ``theta_o = 0`` is ``s = 0``.

The instrument's axes (source zenith, signed detector zenith, detector plane, sample rotation) map
to the fabric frame with :func:`axes_to_fabric` / :func:`fabric_to_axes`; the beam-block test
(:func:`beam_blocked`) is the one rule that plan checks, the driver and the mock controller share.

References
----------
docs/physics.md section 1 (frames); docs/instrument.md (axes and the beam-block zone).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "BEAM_BLOCK_MIN_ANGLE_DEG",
    "axes_to_fabric",
    "beam_blocked",
    "detector_direction",
    "direction",
    "fabric_to_axes",
    "in_plane_geometry",
    "signed_angle",
    "source_detector_angle_deg",
    "source_direction",
    "spherical_angles",
]

#: Smallest angle between the source and detector directions the instrument can measure (degrees).
BEAM_BLOCK_MIN_ANGLE_DEG = 5.0


def direction(theta_deg, phi_deg):
    """Unit vectors ``(..., 3)`` of the fabric-frame directions ``(theta, phi)`` in degrees.

    Examples
    --------
    >>> [round(float(c), 6) for c in direction(90.0, 90.0)]
    [0.0, 1.0, 0.0]
    """
    t = np.radians(np.asarray(theta_deg, dtype=float))
    p = np.radians(np.asarray(phi_deg, dtype=float))
    t, p = np.broadcast_arrays(t, p)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def spherical_angles(w):
    """``(theta, phi)`` in degrees of unit vectors ``w`` (``(..., 3)``), ``phi`` in [0, 360).

    ``theta`` is computed as ``2 asin(|w - z| / 2)``, accurate near the normal.

    Examples
    --------
    >>> t, p = spherical_angles([0.0, -1.0, 0.0])
    >>> round(float(t), 9), float(p)
    (90.0, 270.0)
    """
    w = np.asarray(w, dtype=float)
    dist = np.sqrt(w[..., 0] ** 2 + w[..., 1] ** 2 + (w[..., 2] - 1.0) ** 2)
    theta = np.degrees(2.0 * np.arcsin(np.clip(0.5 * dist, 0.0, 1.0)))
    phi = np.mod(np.degrees(np.arctan2(w[..., 1], w[..., 0])), 360.0)
    phi = np.where(phi >= 360.0, 0.0, phi)
    return theta, phi


def signed_angle(theta_i, phi_i, theta_o, phi_o):
    """Signed in-plane observation angle ``s`` (degrees), NaN where ``w_o`` is out of the plane.

    docs/physics.md section 1: with the source at azimuth ``phi_i``, ``s >= 0`` (mirror side) means
    ``phi_o = phi_i + 180`` and ``s < 0`` (source side) means ``phi_o = phi_i``; ``theta_o = 0`` is
    ``s = 0``.

    Examples
    --------
    >>> float(signed_angle(30, 0, 40, 180)), float(signed_angle(30, 0, 40, 0))
    (40.0, -40.0)
    """
    theta_i, phi_i, theta_o, phi_o = np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (theta_i, phi_i, theta_o, phi_o)))
    dphi = np.mod(phi_o - phi_i, 360.0)
    tol = 1e-6
    mirror = np.abs(dphi - 180.0) < tol
    source = (dphi < tol) | (dphi > 360.0 - tol)
    s = np.where(mirror, theta_o, np.where(source, -theta_o, np.nan))
    s = np.where(np.abs(theta_o) < tol, 0.0, s)
    return s[()] if s.ndim == 0 else s


def in_plane_geometry(theta_i, s, phi_i=0.0):
    """``(theta_o, phi_o)`` in degrees of the in-plane direction with signed angle ``s``.

    Examples
    --------
    >>> in_plane_geometry(30.0, -20.0, phi_i=90.0)
    (20.0, 90.0)
    """
    s = np.asarray(s, dtype=float)
    phi_i = np.asarray(phi_i, dtype=float)
    theta_o = np.abs(s)
    phi_o = np.mod(np.where(s >= 0.0, phi_i + 180.0, phi_i), 360.0)
    if theta_o.ndim == 0 and phi_o.ndim == 0:
        return float(theta_o), float(phi_o)
    return theta_o, phi_o


def source_direction(theta_i_deg: float) -> tuple[float, float, float]:
    """Unit vector towards the source in the instrument frame.

    The instrument frame has z = sample normal and x along the plane of incidence, towards the
    source: ``w_i = (sin theta_i, 0, cos theta_i)``.
    """
    t = math.radians(theta_i_deg)
    return math.sin(t), 0.0, math.cos(t)


def detector_direction(s_deg: float, detector_plane_deg: float) -> tuple[float, float, float]:
    """Unit vector towards the detector in the instrument frame.

    ``w_o = (-sin s cos p, -sin s sin p, cos s)`` with ``s`` the signed detector zenith and ``p``
    the detector-plane azimuth: for ``p = 0``, ``s > 0`` is the mirror side (instrument azimuth
    180 deg) and ``s < 0`` the source side (azimuth 0).
    """
    s, p = math.radians(s_deg), math.radians(detector_plane_deg)
    return -math.sin(s) * math.cos(p), -math.sin(s) * math.sin(p), math.cos(s)


def source_detector_angle_deg(theta_i_deg: float, s_deg: float, detector_plane_deg: float) -> float:
    """Angle in degrees between the source and detector directions (computed in 3D).

    Uses ``atan2(|w_i x w_o|, w_i . w_o)``, accurate at small angles.
    """
    a = source_direction(theta_i_deg)
    b = detector_direction(s_deg, detector_plane_deg)
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return math.degrees(math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), dot))


def beam_blocked(theta_i_deg: float, s_deg: float, detector_plane_deg: float) -> bool:
    """Beam-block rule shared by the driver (plan checks) and the controller (mock).

    The configuration is blocked when the angle between the detector direction and the source
    direction is *strictly less* than 5 degrees (:data:`BEAM_BLOCK_MIN_ANGLE_DEG`); exactly 5
    degrees is allowed. A tolerance of 1e-9 deg absorbs floating-point error, so positions given
    in whole millidegrees decide exactly. The sample rotation plays no part. Only destinations
    are checked, not the path of a move.

    Examples
    --------
    >>> beam_blocked(0.0, 0.0, 0.0)       # normal/normal: never measured
    True
    >>> beam_blocked(30.0, -25.0, 0.0)    # in plane, source side, exactly 5 deg apart
    False
    >>> beam_blocked(30.0, -26.0, 0.0)
    True
    """
    return source_detector_angle_deg(theta_i_deg, s_deg, detector_plane_deg) < BEAM_BLOCK_MIN_ANGLE_DEG - 1e-9


def axes_to_fabric(source_zenith_deg: float, detector_zenith_deg: float, detector_plane_deg: float,
                   sample_rotation_deg: float) -> tuple[float, float, float, float]:
    """Axis positions (degrees) to fabric-frame angles ``(theta_i, phi_i, theta_o, phi_o)``.

    The sample rotation reading *is* ``phi_i`` (source azimuth from the warp, docs/physics.md section
    1); a direction at instrument azimuth ``a`` has fabric azimuth ``a + phi_i``. The detector is
    at instrument azimuth ``180 + p`` for ``s >= 0`` and ``p`` for ``s < 0``. Hence, in plane
    (``p = 0``), ``s >= 0`` gives ``phi_o = phi_i + 180`` and ``s < 0`` gives ``phi_o = phi_i``,
    the dataset's signed-angle convention. Azimuths are returned in [0, 360); ``phi_o`` is
    reported as ``phi_i + 180`` (mod 360) when ``theta_o = 0``.
    """
    theta_i = float(source_zenith_deg)
    phi_i = float(sample_rotation_deg) % 360.0
    s = float(detector_zenith_deg)
    theta_o = abs(s)
    a = (180.0 + detector_plane_deg) if s >= 0 else float(detector_plane_deg)
    phi_o = (a + phi_i) % 360.0
    return theta_i, phi_i, theta_o, phi_o


def fabric_to_axes(theta_i: float, phi_i: float, theta_o: float, phi_o: float
                   ) -> tuple[float, float, float, float]:
    """Fabric-frame angles (degrees) to axis positions ``(source, detector, plane, rotation)``.

    Inverse of :func:`axes_to_fabric` with the plane in [0, 180): the relative azimuth
    ``a = phi_o - phi_i`` (mod 360) in [180, 360) is reached with ``s = +theta_o, p = a - 180``,
    in [0, 180) with ``s = -theta_o, p = a``. ``theta_o = 0`` gives ``s = 0, p = 0``.
    """
    rot = float(phi_i) % 360.0
    if theta_o == 0:
        return float(theta_i), 0.0, 0.0, rot
    a = (float(phi_o) - rot) % 360.0
    if a >= 180.0:
        return float(theta_i), float(theta_o), a - 180.0, rot
    return float(theta_i), -float(theta_o), a, rot
