"""A validated plan in memory: its settings, its points, the order they are measured in, the check.

:class:`Plan` (with :class:`AcquisitionSettings` and :class:`Procedure`) expands into
:class:`PlanPoint` geometries (axis positions and fabric-frame angles, :func:`retro_ring` included);
:meth:`Plan.check` refuses what the controller cannot reach and orders the rest
(:func:`order_points`, :func:`estimate_duration_s`) into a :class:`PlanCheck`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from gonio.acquisition.plan.schema import PROCEDURE_STEPS, RETRO_RING_AZIMUTHS
from gonio.data.geometry import axes_to_fabric, beam_blocked
from gonio.instrument.modbus_map import AXES, deg_to_mdeg

__all__ = ["Procedure", "AcquisitionSettings", "PlanPoint", "PlanCheck", "Plan", "retro_ring", "order_points",
           "estimate_duration_s"]


@dataclass(frozen=True)
class Procedure:
    """The session's steps after connecting (see the module docstring).

    Names of :data:`PROCEDURE_STEPS` in order, and ``recalibrate_every`` points (0 = never).
    """

    steps: tuple[str, ...] = PROCEDURE_STEPS
    recalibrate_every: int = 0


@dataclass(frozen=True)
class AcquisitionSettings:
    """Integration time / gain policy and timing of one plan.

    Auto-ranging starts every reading at ``(itime_ms, gain)`` and steps down
    (:meth:`AcquisitionSettings.ladder`) while the head reports saturation. The default gain is x1:
    the shot-noise-limited relative error ``1/sqrt(K t beta cos theta_o)`` does not depend on the
    gain (it only lifts the signal above the read noise), so a higher starting gain mostly costs
    saturated readings.
    """

    itime_ms: int = 100
    gain: int = 0
    min_itime_ms: int = 1
    readings: int = 8
    repetitions: int = 1
    settle_ms: float = 20.0
    velocity_deg_s: float = 20.0
    calibration_max_age_min: float = 120.0

    def ladder(self) -> list[tuple[int, int]]:
        """Auto-ranging ladder ``[(itime_ms, gain), ...]`` from the most sensitive setting down.

        Every point starts at step 0; a saturated reading moves one step down: the gain first
        (a factor 4 each), then the integration time (halved, whole milliseconds, down to
        ``min_itime_ms``).
        """
        steps = [(self.itime_ms, g) for g in range(self.gain, -1, -1)]
        itime = self.itime_ms
        while itime // 2 >= self.min_itime_ms:
            itime //= 2
            steps.append((itime, 0))
        if steps[-1][0] > self.min_itime_ms:
            steps.append((self.min_itime_ms, 0))
        return steps


@dataclass(frozen=True)
class PlanPoint:
    """One geometry of a plan: axis positions (deg) and the fabric-frame angles (deg)."""

    source_deg: float
    detector_deg: float
    plane_deg: float
    rotation_deg: float
    theta_i: float
    phi_i: float
    theta_o: float
    phi_o: float

    @property
    def axes_deg(self) -> tuple[float, float, float, float]:
        """Axis targets (source zenith, detector zenith, detector plane, sample rotation)."""
        return (self.source_deg, self.detector_deg, self.plane_deg, self.rotation_deg)

    @property
    def key(self) -> tuple[float, float, float, float]:
        """Fabric-frame geometry ``(theta_i, phi_i, theta_o, phi_o)``, rounded to 1e-6 deg."""
        return (round(self.theta_i, 6), round(self.phi_i, 6), round(self.theta_o, 6), round(self.phi_o, 6))


@dataclass
class PlanCheck:
    """Result of :meth:`Plan.check`: measurable points in motion order and the refused ones."""

    ordered: list[PlanPoint]
    blocked: list[PlanPoint]
    out_of_limits: list[tuple[PlanPoint, str]]
    estimated_s: float
    blocked_expected: bool = False

    @property
    def ok(self) -> bool:
        """True when nothing is out of limits and no beam-block point is unexpected."""
        return not self.out_of_limits and (self.blocked_expected or not self.blocked)

    def refusal(self, plan_name: str) -> str | None:
        """Why the plan cannot be acquired, in one line (None when :attr:`ok`).

        The one validation shared by ``gonio check-plan`` (which lists the points) and
        ``gonio acquire`` (which refuses to start).
        """
        if self.ok:
            return None
        parts = []
        if self.out_of_limits:
            _, why = self.out_of_limits[0]
            parts.append(f"{len(self.out_of_limits)} out of the soft limits (first: {why})")
        if self.blocked and not self.blocked_expected:
            parts.append(f"{len(self.blocked)} in the beam-block zone and skip_blocked = false")
        return (f"plan {plan_name}: {'; '.join(parts)}; `gonio check-plan` lists them: fix the "
                "plan (or set skip_blocked = true for expected beam-block points)")


@dataclass
class Plan:
    """A validated acquisition plan (its TOML schema: :data:`gonio.acquisition.plan.SCHEMA`)."""

    name: str
    description: str
    path: Path
    sha256: str
    sample: dict
    wavelengths_nm: np.ndarray
    incidence_deg: list[float]
    rotation_deg: list[float]
    in_plane_deg: list[float]
    directions_deg: list[tuple[float, float]]
    skip_blocked: bool
    acquisition: AcquisitionSettings
    white_standard: str
    reference_deg: tuple[float, float]
    procedure: Procedure = field(default_factory=Procedure)
    retro_ring_deg: list[float] = field(default_factory=list)
    retro_ring_azimuths: int = RETRO_RING_AZIMUTHS
    _points: list[PlanPoint] | None = field(default=None, repr=False)

    def points(self) -> list[PlanPoint]:
        """Every requested geometry, in plan order, duplicates (same fabric geometry) removed."""
        if self._points is not None:
            return self._points
        axes = []
        for rho in self.rotation_deg:
            for ti in self.incidence_deg:
                for s in self.in_plane_deg:
                    axes.append((ti, s, 0.0, rho))
                ring = [d for r in self.retro_ring_deg for d in retro_ring(ti, r, self.retro_ring_azimuths)] \
                    if ti > 0 else []
                for to, dphi in list(self.directions_deg) + ring:
                    rel = np.mod(dphi, 360.0)
                    if rel >= 180.0:
                        axes.append((ti, to, rel - 180.0, rho))
                    else:
                        axes.append((ti, -to if to > 0 else 0.0, rel if to > 0 else 0.0, rho))
        out, seen = [], set()
        for a in axes:
            g = axes_to_fabric(*a)
            p = PlanPoint(float(a[0]), float(a[1]), float(a[2]), float(a[3]), *g)
            if p.key not in seen:
                seen.add(p.key)
                out.append(p)
        self._points = out
        return out

    def geometries(self, measurable_only: bool = False) -> pd.DataFrame:
        """Requested geometries: DataFrame ``theta_i, phi_i, theta_o, phi_o`` (deg, fabric frame).

        Every geometry the plan asks for, in plan order (a model can be evaluated where the
        instrument cannot measure); ``measurable_only`` keeps only those :meth:`check` accepts,
        in motion order.
        """
        pts = self.check().ordered if measurable_only else self.points()
        return pd.DataFrame({
            "theta_i": [p.theta_i for p in pts], "phi_i": [p.phi_i for p in pts],
            "theta_o": [p.theta_o for p in pts], "phi_o": [p.phi_o for p in pts]})

    @property
    def n_measurements(self) -> int:
        """Number of (geometry, wavelength) pairs requested."""
        return len(self.points()) * len(self.wavelengths_nm)

    def check(self, *, move_overhead_s: float = 0.05, read_overhead_s: float = 0.004) -> PlanCheck:
        """Refuse points out of the soft limits or in the beam-block zone, order the rest.

        The rules are the controller's (soft limits of
        :data:`~gonio.instrument.modbus_map.AXES` in whole millidegrees,
        :func:`~gonio.data.geometry.beam_blocked`).

        Parameters
        ----------
        move_overhead_s, read_overhead_s
            Per-move and per-command overheads for the duration estimate.

        Returns
        -------
        PlanCheck
            Measurable points ordered to minimise motion (by rotation, incidence and detector
            plane, serpentine over the detector angle), refused points, and the estimated
            duration in seconds at real speed.
        """
        ok, blocked, bad = [], [], []
        for p in self.points():
            reason = None
            for axis, v in zip(AXES, p.axes_deg, strict=True):
                if not axis.within_limits(deg_to_mdeg(v)):
                    reason = (f"{axis.name} at {v:g} deg outside the soft limits "
                              f"{axis.min_mdeg / 1000:g}..{axis.max_mdeg / 1000:g} deg")
                    break
            if reason:
                bad.append((p, reason))
                continue
            if beam_blocked(p.source_deg, p.detector_deg, p.plane_deg):
                blocked.append(p)
            else:
                ok.append(p)
        ordered = order_points(ok)
        est = estimate_duration_s(self, ordered, move_overhead_s, read_overhead_s)
        return PlanCheck(ordered=ordered, blocked=blocked, out_of_limits=bad, estimated_s=est,
                         blocked_expected=self.skip_blocked)


def retro_ring(theta_i_deg: float, radius_deg: float, azimuths: int = RETRO_RING_AZIMUTHS
               ) -> list[tuple[float, float]]:
    """``(theta_o, phi_o - phi_i)`` (deg) of a ring of directions about the retro-reflection direction.

    ``azimuths`` directions ``radius_deg`` from the retro-reflection (source) direction at incidence
    ``theta_i_deg``, evenly spaced around it starting towards the normal; directions below 85 deg of
    zenith only (the detector's reach).

    >>> [(round(t, 3), round(p, 3)) for t, p in retro_ring(40.0, 6.0, 2)]
    [(34.0, 0.0), (46.0, 0.0)]
    """
    ti = math.radians(theta_i_deg)
    w = np.array([math.sin(ti), 0.0, math.cos(ti)])          # towards the source, phi_i = 0
    e1 = np.array([-math.cos(ti), 0.0, math.sin(ti)])        # in the plane of incidence, towards the normal
    e2 = np.array([0.0, 1.0, 0.0])
    r = math.radians(radius_deg)
    out = []
    for k in range(azimuths):
        a = 2.0 * math.pi * k / azimuths
        d = math.cos(r) * w + math.sin(r) * (math.cos(a) * e1 + math.sin(a) * e2)
        theta_o = math.degrees(math.acos(max(-1.0, min(1.0, float(d[2])))))
        if theta_o >= 85.0:
            continue
        phi = math.degrees(math.atan2(float(d[1]), float(d[0]))) if theta_o > 1e-9 else 0.0
        out.append((round(theta_o, 6), round(phi % 360.0, 6)))
    return out


def order_points(points: list[PlanPoint]) -> list[PlanPoint]:
    """Order points to minimise motion: rotation, incidence, detector plane, serpentine detector."""
    groups: dict[tuple[float, float, float], list[PlanPoint]] = {}
    for p in points:
        groups.setdefault((p.rotation_deg, p.source_deg, p.plane_deg), []).append(p)
    out: list[PlanPoint] = []
    forward = True
    for key in sorted(groups):
        g = sorted(groups[key], key=lambda p: p.detector_deg, reverse=not forward)
        out.extend(g)
        forward = not forward
    return out


def estimate_duration_s(plan: Plan, ordered: list[PlanPoint], move_overhead_s: float = 0.05,
                        read_overhead_s: float = 0.004) -> float:
    """Estimated duration (s, real speed): homing, calibration, moves, settling and readings."""
    a = plan.acquisition
    v = a.velocity_deg_s
    read_s = a.repetitions * (a.readings * a.itime_ms / 1000.0 + read_overhead_s)
    per_wavelength = read_s + 2 * read_overhead_s
    n_wl = len(plan.wavelengths_nm)
    # homing (all axes from up to 180 deg) and the calibration: darks per ladder step, reference
    total = 180.0 / v + a.readings * sum(t for t, _ in a.ladder()) / 1000.0
    total += n_wl * per_wavelength + 90.0 / v
    pos = np.array([plan.reference_deg[0], plan.reference_deg[1], 0.0, 0.0])
    for p in ordered:
        target = np.array(p.axes_deg)
        total += float(np.max(np.abs(target - pos))) / v + a.settle_ms / 1000.0 + move_overhead_s
        total += n_wl * per_wavelength
        pos = target
    return total
