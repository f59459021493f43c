"""Objects of the simulated cell, seen by ray casting.

Every object is fixed in one frame of the cell, ``"base"`` or ``"flange"`` (its
``frame`` attribute), and is described in that frame's coordinates, in mm. The cell
casts the sensor's laser fan at it through one method::

    distances_mm = obj.intersect(origins_mm, directions)

``origins_mm`` (n, 3) and ``directions`` (n, 3, unit vectors) are rays expressed in the
object's frame; the answer is the distance along each ray to its first hit on the
object (a ray meets the object at ``origin + distance * direction``), ``inf`` where the
ray misses or where the object lies behind the origin. Distances do not depend on the
frame, so the cell can compare the answers of objects fixed in different frames and keep
the nearest (occlusion). An object may also tell the sphere it lies within,
``centre_mm, radius_mm = obj.bounding_sphere_mm()`` (in its frame): casting many poses
at once (:mod:`spherecal.sim.streams`) then skips the poses whose laser fan cannot reach it.

Objects:

- :class:`Sphere`: a reference sphere (solid; a ray starting inside it sees nothing).
- :class:`BallBar`: two spheres of one radius at a certified centre distance.
- :class:`FlatPlate`: a thin finite rectangle, seen from both sides.
- :class:`CarDoorPanel`: a smooth doubly-curved sheet over a rounded rectangle, with a
  softened crease ("character line") across it, shaped like the skin of a car door;
  intersected by ray marching and bisection to better than 1e-6 mm.
"""

from __future__ import annotations

from typing import Literal, Protocol, runtime_checkable

import numpy as np

from spherecal.core.models import Pose

ObjectFrame = Literal["base", "flange"]
_FRAMES = ("base", "flange")


@runtime_checkable
class SceneObject(Protocol):
    """What the simulated cell needs from an object."""

    frame: ObjectFrame
    name: str

    def intersect(self, origins_mm: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Distance (mm) along each ray (expressed in ``frame``) to the first hit; inf on a miss."""
        ...


def _check_frame(frame: str, what: str) -> str:
    if frame not in _FRAMES:
        raise ValueError(f"{what}: frame must be 'base' or 'flange', got {frame!r}")
    return frame


def _rays(origins_mm, directions) -> tuple[np.ndarray, np.ndarray]:
    o = np.asarray(origins_mm, dtype=float)
    d = np.asarray(directions, dtype=float)
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise ValueError(f"rays: origins and directions must both be (n, 3), got {o.shape} and {d.shape}")
    return o, d


def _positive(value: float, name: str) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive number of mm, got {value}")
    return value


def _in_local(frame_from_local: Pose, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays of the object's frame expressed in the object's local frame."""
    R = frame_from_local.rotation_matrix
    t = frame_from_local.translation
    return (o - t) @ R, d @ R


class Sphere:
    """A solid sphere: ``centre_mm`` in ``frame``, radius ``radius_mm``.

    The first hit is the nearer root of |o + s d - c| = r when it is positive; a ray
    whose origin is inside the sphere, or that points away from it, misses."""

    def __init__(self, centre_mm, radius_mm: float, frame: ObjectFrame = "base", name: str = "sphere"):
        self.centre_mm = np.asarray(centre_mm, dtype=float).reshape(3)
        if not np.all(np.isfinite(self.centre_mm)):
            raise ValueError(f"{name}: centre_mm must be finite, got {self.centre_mm.tolist()}")
        self.radius_mm = _positive(radius_mm, f"{name}: radius_mm")
        self.frame = _check_frame(frame, name)
        self.name = name

    def intersect(self, origins_mm, directions) -> np.ndarray:
        o, d = _rays(origins_mm, directions)
        w = o - self.centre_mm
        b = np.einsum("ij,ij->i", d, w)
        disc = b * b - (np.einsum("ij,ij->i", w, w) - self.radius_mm**2)
        out = np.full(len(o), np.inf)
        hit = disc > 0
        s = -b[hit] - np.sqrt(disc[hit])
        out[np.flatnonzero(hit)[s > 0]] = s[s > 0]
        return out

    def intersect_laser_plane(self, centre_in_sensor_mm, apex_yz_mm, directions_yz) -> np.ndarray:
        """Distances along rays that lie in the sensor's x = 0 plane, given the centre in
        the sensor frame: the plane cuts the sphere in a circle of radius
        sqrt(r^2 - x_c^2), intersected in 2-D. Same answer as :meth:`intersect` (to
        rounding), cheaper, and the arithmetic the cell has always used."""
        c = np.asarray(centre_in_sensor_mm, dtype=float)
        r = self.radius_mm
        out = np.full(len(directions_yz), np.inf)
        if abs(c[0]) >= r:
            return out
        rho = np.sqrt(r * r - c[0] * c[0])
        w = np.asarray(apex_yz_mm, dtype=float) - c[1:]
        b = directions_yz @ w
        disc = b * b - (w @ w - rho * rho)
        hit = disc > 0
        s = -b[hit] - np.sqrt(disc[hit])
        out[np.flatnonzero(hit)[s > 0]] = s[s > 0]
        return out

    def __repr__(self) -> str:
        return f"Sphere(centre_mm={self.centre_mm.tolist()}, radius_mm={self.radius_mm}, frame={self.frame!r})"


class BallBar:
    """Two spheres of radius ``radius_mm`` with centres ``centre_a_mm`` and ``centre_b_mm``
    (in ``frame``). ``certified_distance_mm`` defaults to the true centre distance (a
    perfectly calibrated bar); give another value to model a calibration certificate
    that is off."""

    def __init__(
        self,
        centre_a_mm,
        centre_b_mm,
        radius_mm: float,
        frame: ObjectFrame = "base",
        certified_distance_mm: float | None = None,
        name: str = "ball_bar",
    ):
        self.frame = _check_frame(frame, name)
        self.name = name
        self.sphere_a = Sphere(centre_a_mm, radius_mm, frame, name=f"{name}.a")
        self.sphere_b = Sphere(centre_b_mm, radius_mm, frame, name=f"{name}.b")
        dist = float(np.linalg.norm(self.sphere_b.centre_mm - self.sphere_a.centre_mm))
        if dist <= 2 * self.sphere_a.radius_mm:
            raise ValueError(
                f"{name}: the spheres overlap (centre distance {dist:.3f} mm <= diameter "
                f"{2 * self.sphere_a.radius_mm:.3f} mm); place the centres further apart"
            )
        self.true_distance_mm = dist
        self.certified_distance_mm = dist if certified_distance_mm is None else _positive(
            certified_distance_mm, f"{name}: certified_distance_mm"
        )

    @property
    def radius_mm(self) -> float:
        return self.sphere_a.radius_mm

    def intersect(self, origins_mm, directions) -> np.ndarray:
        return np.minimum(self.sphere_a.intersect(origins_mm, directions), self.sphere_b.intersect(origins_mm, directions))

    def __repr__(self) -> str:
        return (
            f"BallBar(centre_a_mm={self.sphere_a.centre_mm.tolist()}, centre_b_mm={self.sphere_b.centre_mm.tolist()}, "
            f"radius_mm={self.radius_mm}, frame={self.frame!r})"
        )


class FlatPlate:
    """A thin rectangular plate, ``length_mm`` along its local x by ``width_mm`` along its
    local y, centred on the local origin in the local z = 0 plane. ``frame_from_plate``
    places it in ``frame``. Seen from both sides; the edges are sharp."""

    def __init__(
        self,
        frame_from_plate: Pose,
        length_mm: float,
        width_mm: float,
        frame: ObjectFrame = "base",
        name: str = "flat_plate",
    ):
        self.frame_from_plate = frame_from_plate
        self.length_mm = _positive(length_mm, f"{name}: length_mm")
        self.width_mm = _positive(width_mm, f"{name}: width_mm")
        self.frame = _check_frame(frame, name)
        self.name = name

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the plate (its local z) in ``frame``."""
        return self.frame_from_plate.rotation_matrix[:, 2].copy()

    def bounding_sphere_mm(self) -> tuple[np.ndarray, float]:
        """The sphere the plate lies within: (centre (3,), radius), ``frame``, mm."""
        return self.frame_from_plate.translation.copy(), 0.5 * float(np.hypot(self.length_mm, self.width_mm))

    def intersect(self, origins_mm, directions) -> np.ndarray:
        o, d = _in_local(self.frame_from_plate, *_rays(origins_mm, directions))
        out = np.full(len(o), np.inf)
        dz = d[:, 2]
        ok = np.abs(dz) > 1e-15
        s = np.full(len(o), -1.0)
        s[ok] = -o[ok, 2] / dz[ok]
        p = o + s[:, None] * d
        hit = ok & (s > 0) & (np.abs(p[:, 0]) <= self.length_mm / 2) & (np.abs(p[:, 1]) <= self.width_mm / 2)
        out[hit] = s[hit]
        return out

    def __repr__(self) -> str:
        return f"FlatPlate({self.length_mm} x {self.width_mm} mm, frame={self.frame!r})"


class CarDoorPanel:
    """A curved sheet shaped like the outer skin of a car door.

    In its local frame (u = x, v = y, height z, mm) the surface is the height field::

        z = f(u, v) = -u^2 / (2 R_u) - v^2 / (2 R_v) - k * sqrt((v - v_c(u))^2 + e^2) + k * e
        v_c(u) = crease_offset_mm + crease_slope * u

    over the rounded rectangle |u| <= length/2, |v| <= height/2 with corner radius
    ``corner_radius_mm``: a dome with the curvature radii ``radius_u_mm`` (along the door)
    and ``radius_v_mm`` (top to bottom), folded along a straight crease line whose sides
    meet at an angle of about ``2 k`` rad, softened over about ``e =
    crease_softness_mm``. With positive radii and k >= 0, f is concave, so the sheet is
    the top of a convex body (handy for tests with known answers), but nothing in the
    intersection relies on that. ``frame_from_panel`` places the panel in ``frame``;
    its local +z is the outward side.

    Intersection: the ray is clipped to the panel's bounding box, sampled at
    ``n_march`` equal steps for a sign change of ``g(s) = z(s) - f(u(s), v(s))``,
    then each bracketed root is bisected until the bracket is below ``tolerance_mm``;
    the first root inside the rounded rectangle wins. A ray that enters and leaves the
    sheet between two samples (grazing within ``step`` of tangency) is missed.
    """

    def __init__(
        self,
        frame_from_panel: Pose,
        length_mm: float = 1000.0,
        height_mm: float = 700.0,
        corner_radius_mm: float = 80.0,
        radius_u_mm: float = 4000.0,
        radius_v_mm: float = 1500.0,
        crease_depth: float = 0.05,
        crease_offset_mm: float = 60.0,
        crease_slope: float = 0.03,
        crease_softness_mm: float = 2.0,
        frame: ObjectFrame = "base",
        n_march: int = 256,
        tolerance_mm: float = 1e-8,
        name: str = "car_door_panel",
    ):
        self.frame_from_panel = frame_from_panel
        self.length_mm = _positive(length_mm, f"{name}: length_mm")
        self.height_mm = _positive(height_mm, f"{name}: height_mm")
        self.corner_radius_mm = float(corner_radius_mm)
        if not 0 <= self.corner_radius_mm <= min(self.length_mm, self.height_mm) / 2:
            raise ValueError(
                f"{name}: corner_radius_mm must be in [0, min(length, height)/2], got {corner_radius_mm}"
            )
        self.radius_u_mm = _positive(radius_u_mm, f"{name}: radius_u_mm")
        self.radius_v_mm = _positive(radius_v_mm, f"{name}: radius_v_mm")
        if crease_depth < 0:
            raise ValueError(f"{name}: crease_depth must be >= 0 (a slope, dimensionless), got {crease_depth}")
        self.crease_depth = float(crease_depth)
        self.crease_offset_mm = float(crease_offset_mm)
        self.crease_slope = float(crease_slope)
        self.crease_softness_mm = _positive(crease_softness_mm, f"{name}: crease_softness_mm")
        if n_march < 8:
            raise ValueError(f"{name}: n_march must be >= 8, got {n_march}")
        self.n_march = int(n_march)
        self.tolerance_mm = _positive(tolerance_mm, f"{name}: tolerance_mm")
        self.frame = _check_frame(frame, name)
        self.name = name
        a, b = self.length_mm / 2, self.height_mm / 2
        k, e = self.crease_depth, self.crease_softness_mm
        far = b + abs(self.crease_slope) * a + abs(self.crease_offset_mm)
        self._z_min = -(a * a / (2 * self.radius_u_mm) + b * b / (2 * self.radius_v_mm)) - k * np.hypot(far, e) + k * e - 1.0
        self._z_max = 1.0  # f <= 0 everywhere; one mm of margin each side

    # surface ---------------------------------------------------------------------------
    def surface_z_mm(self, u_mm, v_mm) -> np.ndarray:
        """f(u, v): the sheet's local z at local (u, v), mm (defined beyond the outline too)."""
        u = np.asarray(u_mm, dtype=float)
        v = np.asarray(v_mm, dtype=float)
        k, e = self.crease_depth, self.crease_softness_mm
        vc = self.crease_offset_mm + self.crease_slope * u
        return -u * u / (2 * self.radius_u_mm) - v * v / (2 * self.radius_v_mm) - k * np.sqrt((v - vc) ** 2 + e * e) + k * e

    def contains(self, u_mm, v_mm) -> np.ndarray:
        """True where local (u, v) lies inside the rounded-rectangle outline."""
        u = np.abs(np.asarray(u_mm, dtype=float))
        v = np.abs(np.asarray(v_mm, dtype=float))
        rc = self.corner_radius_mm
        a, b = self.length_mm / 2, self.height_mm / 2
        qu = np.maximum(u - (a - rc), 0.0)
        qv = np.maximum(v - (b - rc), 0.0)
        return (u <= a) & (v <= b) & (qu * qu + qv * qv <= rc * rc)

    def surface_point_mm(self, u_mm, v_mm) -> np.ndarray:
        """Points (..., 3) of the sheet in ``frame`` at local (u, v)."""
        u = np.asarray(u_mm, dtype=float)
        v = np.asarray(v_mm, dtype=float)
        local = np.stack(np.broadcast_arrays(u, v, self.surface_z_mm(u, v)), axis=-1)
        return self.frame_from_panel.apply(local)

    # ray casting -----------------------------------------------------------------------
    def bounding_sphere_mm(self) -> tuple[np.ndarray, float]:
        """The sphere the panel lies within (around its bounding box): (centre (3,), radius), ``frame``, mm."""
        z_mid = 0.5 * (self._z_min + self._z_max)
        half = 0.5 * np.array([self.length_mm, self.height_mm, self._z_max - self._z_min])
        return self.frame_from_panel.apply(np.array([0.0, 0.0, z_mid])), float(np.linalg.norm(half))

    def intersect(self, origins_mm, directions) -> np.ndarray:
        o, d = _in_local(self.frame_from_panel, *_rays(origins_mm, directions))
        n = len(o)
        out = np.full(n, np.inf)
        if n == 0:
            return out
        # slab test against the bounding box
        lo = np.array([-self.length_mm / 2, -self.height_mm / 2, self._z_min])
        hi = -lo
        hi[2] = self._z_max
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1 = (lo - o) * inv
            t2 = (hi - o) * inv
        t_near = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
        t_far = np.where(np.isnan(t1), np.inf, np.maximum(t1, t2))
        # a ray parallel to a slab and outside it gives +-inf bounds of one sign: a miss
        s0 = np.maximum(np.max(t_near, axis=1), 0.0)
        s1 = np.min(t_far, axis=1)
        live = np.flatnonzero(s1 > s0)
        if len(live) == 0:
            return out
        o, d, s0, s1 = o[live], d[live], s0[live], s1[live]
        frac = np.linspace(0.0, 1.0, self.n_march + 1)
        s = s0[:, None] + (s1 - s0)[:, None] * frac  # (r, n_march + 1)
        g = self._g(o[:, None, :], d[:, None, :], s)
        sign = np.signbit(g)
        exact = g == 0
        change = (sign[:, 1:] != sign[:, :-1]) | exact[:, :-1]
        ray, step = np.nonzero(change)
        if len(ray) == 0:
            return out
        a = s[ray, step]
        b = s[ray, step + 1]
        ga = g[ray, step]
        oo, dd = o[ray], d[ray]
        # bisection: keep the bracket [a, b] with g(a) and g(b) of opposite signs
        n_iter = int(np.ceil(np.log2(max(np.max(b - a), self.tolerance_mm) / self.tolerance_mm))) + 1
        for _ in range(n_iter):
            m = 0.5 * (a + b)
            gm = self._g(oo, dd, m)
            left = (np.signbit(gm) != np.signbit(ga)) | (ga == 0)
            b = np.where(left, m, b)
            a = np.where(left, a, m)
            ga = np.where(left, ga, gm)
        root = np.where(ga == 0, a, 0.5 * (a + b))
        p = oo + root[:, None] * dd
        valid = self.contains(p[:, 0], p[:, 1]) & (root > 0)
        best = np.full(len(live), np.inf)
        np.minimum.at(best, ray[valid], root[valid])
        out[live] = best
        return out

    def _g(self, o, d, s) -> np.ndarray:
        """Height of the ray point above the sheet, g(s) = z - f(u, v)."""
        u = o[..., 0] + s * d[..., 0]
        v = o[..., 1] + s * d[..., 1]
        z = o[..., 2] + s * d[..., 2]
        return z - self.surface_z_mm(u, v)

    def __repr__(self) -> str:
        return f"CarDoorPanel({self.length_mm} x {self.height_mm} mm, frame={self.frame!r})"
