r"""Fabric BRDF from the fiber BRDF: summation over warp and weft (the classic baseline: :mod:`simulate.fabric.classic`).

Summation (docs/physics.md section 6). With B the top cell of a fiber lying in the fabric plane and
``R_B = R_surf + R_vol`` its BRDF in the form ``L_o / E_perp`` (:mod:`simulate.fiber`)::

    R_fabric(w_i, w_o) = 1/2 sum_{k in warp, weft} R_B(M_k w_i, M_k w_o)
    f_fabric = R_fabric / cos(theta_i)        beta = pi f_fabric

``M_k`` expresses fabric-frame directions (z = normal, x = warp, y = weft) in the frame of the
fiber (x = fiber axis, z = outward normal of B, y = z x x). A warp fiber lies along x, so
``M_warp = I``; a weft fiber lies along y, and its frame is ``(x_f, y_f, z_f) = (y, -x, z)``::

    M_warp = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    M_weft = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]       (a rotation by -90 deg about z)

A sample rotated by ``rho`` about its normal (warp at azimuth ``rho`` of the frame in which the
directions are given) uses ``M_k Rz(-rho)``: sample rotation rotates ``M_k`` about z. Datasets
state their angles in the fabric frame (``phi_i`` is the sample rotation reading), so the
virtual goniophotometer evaluates at ``rho = 0``.

Only what a plan needs is computed: every geometry gives two fiber-frame pairs; the pairs are
reduced by the cylinder's mirror symmetries (``w_t -> -w_t`` and ``w_b -> -w_b`` applied to both
directions leave ``R_B`` unchanged: the cylinder and the cell B centred on ``psi = 0`` are
symmetric under both mirrors) to a canonical form with ``w_in,x >= 0`` and ``w_in,y >= 0``,
de-duplicated, and sent to ONE :func:`simulate.fiber.volume_brdf` call at the plan's wavelengths.

Uncertainty: the Monte Carlo routes estimate all pairs from the same photons, so the errors of
the warp and weft values are correlated with an unknown (positive) covariance. The propagated
standard error is the bound ``u(R_fabric) = 1/2 (u_warp + u_weft)``, exact for full positive
correlation and never an underestimate (when warp and weft map to the same pair it is exact).

Classic model (the comparison baseline)::

    beta_classic(w_i, w_o, lambda) = rho_d(lambda) + pi f_CT(w_i, w_o)

with ``rho_d`` the fiber's normal-incidence volume albedo (:func:`simulate.fiber.normal_albedo`),
so that colour and energy at normal incidence match the fiber model and only the angular shape
differs, and ``f_CT`` the Cook-Torrance BRDF of :mod:`simulate.optics.microfacet` in the fabric frame
(a flat surface of the fiber's RMS slope and host index). Its hemispherical albedo is
``rho_d + A_CT(theta_i)`` (:func:`simulate.optics.microfacet.directional_albedo`).

The grazing limit ``theta_i = 90`` deg has ``cos(theta_i) = 0``: ``f_fabric`` is undefined there and
such geometries are refused (:class:`FabricError`).

Domain of the summation. ``R_B`` counts the light a fiber intercepts over its whole projected
width (``2 R |w_perp|`` per unit length, light entering its side crosses it and leaves at B),
whereas the fabric receives ``2 R cos(theta_i)`` per fiber: towards grazing incidence the weft
fiber gathers up to ``1 / cos(theta_i)`` times its share - in a real fabric its neighbours shadow
its side. The summation's albedo therefore grows without bound as ``theta_i -> 90`` and exceeds 1
beyond some angle (red cotton: 0.64 at 60 deg, 0.78 at 70, 0.96 at 75, 1.2 at 80, 1.9 at 85 deg, at
700 nm). Geometries beyond :data:`SUMMATION_GRAZING_LIMIT_DEG` raise an ``OpticsDomainWarning``
and :func:`summation_albedo` warns whenever the albedo it finds exceeds 1 (docs/quality.md B: flagged,
never silent). The fabric Monte Carlo (shadowing, masking) is the method for grazing incidence.

References
----------
docs/physics.md sections 5-7. Cook, R. L. & Torrance, K. E. (1982). *ACM TOG* 1(1), 7-24.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from simulate.optics.fresnel import OpticsDomainWarning
from simulate.optics.microfacet import directions_deg

log = logging.getLogger(__name__)

#: Incidence beyond which the summation's energy balance is not trusted (see the module docstring).
SUMMATION_GRAZING_LIMIT_DEG = 70.0

M_WARP = np.eye(3)
M_WEFT = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
#: Decimals to which fiber-frame components are rounded before de-duplication.
_PAIR_DECIMALS = 10


class FabricError(ValueError):
    """A geometry or input the fabric models cannot evaluate (the message says which and why)."""


def rotation_z(angle_deg: float) -> np.ndarray:
    """Rotation matrix by ``angle_deg`` about z (counter-clockwise seen from +z)."""
    a = np.radians(float(angle_deg))
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def fiber_frame_pairs(w_i: np.ndarray, w_o: np.ndarray, rotation_deg: float = 0.0
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fabric-frame pairs ``[G, 3]`` in the frames of the warp and the weft fiber.

    Returns
    -------
    warp_in, warp_out, weft_in, weft_out : numpy.ndarray
        ``M_k Rz(-rotation_deg) w`` for k = warp, weft.
    """
    r = rotation_z(-rotation_deg)
    m_warp, m_weft = M_WARP @ r, M_WEFT @ r
    w_i = np.asarray(w_i, float)
    w_o = np.asarray(w_o, float)
    return w_i @ m_warp.T, w_o @ m_warp.T, w_i @ m_weft.T, w_o @ m_weft.T


def canonical_pairs(w_in: np.ndarray, w_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map fiber-frame pairs to their mirror-symmetric representative (``w_in,x >= 0``, ``w_in,y >= 0``).

    ``w_t -> -w_t`` (x) and ``w_b -> -w_b`` (y) are applied to BOTH directions; where the
    incident component is zero the outgoing one decides, so equivalent pairs coincide.
    """
    w_in = np.array(w_in, float, copy=True)
    w_out = np.array(w_out, float, copy=True)
    for axis in (0, 1):
        a = np.round(w_in[:, axis], _PAIR_DECIMALS)
        b = np.round(w_out[:, axis], _PAIR_DECIMALS)
        flip = (a < 0) | ((a == 0) & (b < 0))
        w_in[flip, axis] *= -1.0
        w_out[flip, axis] *= -1.0
    return w_in, w_out


@dataclass(frozen=True)
class FiberPairs:
    """The unique fiber-frame pairs a set of fabric geometries needs.

    Attributes
    ----------
    w_in, w_out : numpy.ndarray
        ``[U, 3]`` unique canonical pairs (fiber frame).
    warp, weft : numpy.ndarray
        ``[G]`` index into the unique pairs of each geometry's warp and weft pair.
    cos_i : numpy.ndarray
        ``[G]`` ``cos(theta_i)`` of each geometry (fabric frame).
    """

    w_in: np.ndarray
    w_out: np.ndarray
    warp: np.ndarray
    weft: np.ndarray
    cos_i: np.ndarray

    @classmethod
    def from_directions(cls, w_i: np.ndarray, w_o: np.ndarray, rotation_deg: float = 0.0,
                        use_symmetry: bool = True) -> FiberPairs:
        """Pairs for fabric-frame directions ``w_i, w_o`` ``[G, 3]`` (``w_o`` in the upper hemisphere)."""
        w_i = np.atleast_2d(np.asarray(w_i, float))
        w_o = np.atleast_2d(np.asarray(w_o, float))
        if np.any(w_i[:, 2] <= 0) or np.any(w_o[:, 2] < 0):
            raise FabricError("fabric BRDF: the incident direction must be above the fabric "
                              "(theta_i < 90 deg) and the outgoing one not below it")
        if np.any(w_i[:, 2] < np.cos(np.radians(SUMMATION_GRAZING_LIMIT_DEG))):
            warnings.warn(
                f"fabric summation: incidence beyond {SUMMATION_GRAZING_LIMIT_DEG:g} deg: the fiber BRDF counts "
                "the light entering the fiber's side, which neighbouring fibers shadow in a fabric; the "
                "summation overestimates there and its albedo can exceed 1 (use the fabric Monte Carlo)",
                OpticsDomainWarning, stacklevel=3)
        a_in, a_out, b_in, b_out = fiber_frame_pairs(w_i, w_o, rotation_deg)
        w_in = np.concatenate([a_in, b_in])
        w_out = np.concatenate([a_out, b_out])
        if use_symmetry:
            w_in, w_out = canonical_pairs(w_in, w_out)
        key = np.round(np.concatenate([w_in, w_out], axis=1), _PAIR_DECIMALS) + 0.0
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.ravel()
        g = w_i.shape[0]
        return cls(w_in=w_in[first], w_out=w_out[first], warp=inverse[:g], weft=inverse[g:],
                   cos_i=w_i[:, 2].copy())

    @classmethod
    def from_angles(cls, theta_i, phi_i, theta_o, phi_o, rotation_deg: float = 0.0,
                    use_symmetry: bool = True) -> FiberPairs:
        """Pairs for fabric-frame angles in degrees (arrays of equal length)."""
        theta_i = np.asarray(theta_i, float)
        if np.any(theta_i >= 90.0):
            raise FabricError(f"fabric BRDF: theta_i = {float(theta_i.max()):g} deg is not below 90: "
                              "the fabric BRDF R/cos(theta_i) is undefined at grazing incidence")
        return cls.from_directions(directions_deg(theta_i, phi_i), directions_deg(theta_o, phi_o),
                                   rotation_deg, use_symmetry)

    @property
    def n_unique(self) -> int:
        """The number of unique fiber-frame pairs (rows of ``w_in``) the geometries map to."""
        return int(self.w_in.shape[0])


def summation_from_table(pairs: FiberPairs, R_B: np.ndarray, u_R_B: np.ndarray | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """``beta`` ``[G, L]`` of the summation model from ``R_B`` ``[U, L]`` at the unique pairs.

    ``beta = pi / cos(theta_i) * 1/2 (R_B[warp] + R_B[weft])``; ``u_beta`` is the correlated
    bound ``pi / cos(theta_i) * 1/2 (u[warp] + u[weft])`` (module docstring). Pure gathers and
    one multiply: tens of millions of (geometry, wavelength) values per second.
    """
    R_B = np.asarray(R_B, float)
    scale = (0.5 * np.pi / pairs.cos_i)[:, None]
    beta = scale * (R_B[pairs.warp] + R_B[pairs.weft])
    if u_R_B is None:
        return beta, np.zeros_like(beta)
    u = np.asarray(u_R_B, float)
    return beta, scale * (u[pairs.warp] + u[pairs.weft])


def summation_beta(R_B: Any, w_i: np.ndarray, w_o: np.ndarray, rotation_deg: float = 0.0
                   ) -> np.ndarray:
    """``beta`` of the summation model for a callable fiber BRDF ``R_B(w_in [P,3], w_out [P,3]) -> [P, ...]``.

    No symmetry reduction: ``R_B`` is evaluated at the exact warp and weft pairs (this is the
    reference form of the equation; :func:`summation_from_table` is the plan-driven form).
    """
    w_i = np.atleast_2d(np.asarray(w_i, float))
    w_o = np.atleast_2d(np.asarray(w_o, float))
    a_in, a_out, b_in, b_out = fiber_frame_pairs(w_i, w_o, rotation_deg)
    total = np.asarray(R_B(a_in, a_out), float) + np.asarray(R_B(b_in, b_out), float)
    cos_i = w_i[:, 2].reshape((-1,) + (1,) * (total.ndim - 1))
    return 0.5 * np.pi * total / cos_i


def summation_hemispherical_albedo(R_B: Any, theta_i_deg: float, n_theta: int = 24, n_phi: int = 48,
                                   phi_i_deg: float = 0.0) -> np.ndarray:
    """``int R_fabric(w_i, w_o) / cos(theta_i) cos(theta_o) dOmega_o`` by the midpoint rule.

    ``R_B`` is a callable as in :func:`summation_beta`; the quadrature is on ``cos^2 theta_o``
    (uniform in projected solid angle) x ``phi_o``, so a Lambertian ``R_B`` is integrated exactly.
    """
    u = (np.arange(n_theta) + 0.5) / n_theta  # u = sin^2 theta_o, dOmega cos = du dphi / 2
    phi = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    st = np.sqrt(u)
    ct = np.sqrt(1.0 - u)
    uu, pp = np.meshgrid(np.arange(n_theta), np.arange(n_phi), indexing="ij")
    w_o = np.stack([st[uu] * np.cos(phi[pp]), st[uu] * np.sin(phi[pp]), ct[uu]], axis=-1).reshape(-1, 3)
    w_i = np.broadcast_to(directions_deg(theta_i_deg, phi_i_deg), w_o.shape)
    beta = summation_beta(R_B, w_i, w_o)
    f = beta / np.pi
    weight = (0.5 * 2.0 * np.pi / (n_theta * n_phi))  # (du/2) dphi summed over the grid
    return np.sum(f, axis=0) * weight


def hemisphere_grid(n_theta: int, n_phi: int) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint grid over the upper hemisphere, uniform in ``u = sin^2 theta`` and ``phi``.

    Returns directions ``[N, 3]`` and weights ``[N]`` with ``int g(w) cos(theta) dOmega ~
    sum_j weight_j g(w_j)`` (``cos theta dOmega = du dphi / 2``; exact for constant ``g``).
    """
    u = (np.arange(n_theta) + 0.5) / n_theta
    phi = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    uu, pp = np.meshgrid(u, phi, indexing="ij")
    st, ct = np.sqrt(uu.ravel()), np.sqrt(1.0 - uu.ravel())
    w = np.stack([st * np.cos(pp.ravel()), st * np.sin(pp.ravel()), ct], axis=1)
    return w, np.full(w.shape[0], np.pi / (n_theta * n_phi))


def summation_albedo(fiber: Any, theta_i_deg: float, wavelengths_nm: npt.ArrayLike, *,
                     n_theta: int = 8, n_phi: int = 16, surface: bool = True,
                     surface_grid: tuple[int, int] = (256, 256), phi_i_deg: float = 0.0,
                     **mc: Any) -> tuple[np.ndarray, np.ndarray, dict]:
    """Directional-hemispherical albedo of the summation fabric at incidence ``theta_i_deg``.

    ``a(theta_i) = int f_fabric(w_i, w_o) cos(theta_o) dOmega_o``, the volume term by ONE
    :func:`simulate.fiber.volume_brdf` call on an ``n_theta x n_phi`` :func:`hemisphere_grid`
    (symmetry-reduced pairs), the surface term (no Monte Carlo noise) on the finer
    ``surface_grid``. ``mc`` is passed to ``volume_brdf`` (method, target_rel_err, seed, ...).

    Returns
    -------
    albedo, u_albedo : numpy.ndarray
        ``[L]``; ``u`` is the correlated bound (sum of the weighted standard errors).
    info : dict
        ``{"volume": [L], "surface": float, "photons": int}``.
    """
    from simulate import fiber as fiber_mod

    wl = np.atleast_1d(np.asarray(wavelengths_nm, float))
    w_o, weight = hemisphere_grid(n_theta, n_phi)
    w_i = np.broadcast_to(directions_deg(theta_i_deg, phi_i_deg), w_o.shape)
    pairs = FiberPairs.from_directions(w_i, w_o)
    est = fiber_mod.volume_brdf(fiber, pairs.w_in, pairs.w_out, wl, **mc)
    beta, u_beta = summation_from_table(pairs, est.R, est.u_R)
    volume = weight @ (beta / np.pi)
    u_volume = weight @ (u_beta / np.pi)
    surf = 0.0
    if surface:
        ws_o, ws_weight = hemisphere_grid(*surface_grid)
        ws_i = np.broadcast_to(directions_deg(theta_i_deg, phi_i_deg), ws_o.shape)
        pairs_s = FiberPairs.from_directions(ws_i, ws_o)
        with warnings.catch_warnings():
            # the quadrature's outgoing directions approach the horizon, where Cook-Torrance warns;
            # its values stay finite and their weight vanishes there
            warnings.simplefilter("ignore", OpticsDomainWarning)
            r_surf = np.asarray(fiber_mod.surface_brdf(fiber, pairs_s.w_in, pairs_s.w_out), float)
        beta_s, _ = summation_from_table(pairs_s, r_surf[:, None])
        surf = float(ws_weight @ (beta_s[:, 0] / np.pi))
    albedo = volume + surf
    if np.any(albedo > 1.0):
        warnings.warn(
            f"fabric summation: albedo {float(albedo.max()):.3g} > 1 at theta_i = {theta_i_deg:g} deg "
            "(energy not conserved: the summation is outside its domain, see simulate.fabric)",
            OpticsDomainWarning, stacklevel=2)
    return albedo, u_volume, {"volume": volume, "u_volume": u_volume, "surface": surf,
                                     "photons": int(est.photons)}
