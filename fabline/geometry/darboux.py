"""Curvature along each lamella in its Darboux frame (domain.md section 2).

The centreline and its normals are interpolated by cubic splines over the chord-length parameter, so
arc lengths and curvatures are accurate to fourth and second order in the sample spacing. Frame:
tangent t, surface normal n, sideways u = n x t, with dt/ds = k_g u + k_n n and dn/ds = -k_n t - tau_g u;
k_g is read from the centreline's second derivative, k_n and tau_g from the normals' first derivative.
All lengths in millimetres, curvatures in 1/mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from fabline.model.network import Lamella, Network, check_node_stations, project_onto_curve
from fabline.progress import progress

GAUSS_X, GAUSS_W = np.polynomial.legendre.leggauss(5)  # per-interval arc-length quadrature, shared by offsets


@dataclass
class CurveFit:
    """Spline interpolation of a lamella's centreline and normals over the chord-length parameter `tau`.

    One cubic spline carries both, six columns: x, y, z and the normal's three components.
    """

    tau: np.ndarray
    spline: CubicSpline
    s_at_samples: np.ndarray

    @classmethod
    def of(cls, points: np.ndarray, normals: np.ndarray) -> "CurveFit":
        tau = np.concatenate([[0.0], np.cumsum(_norm(np.diff(points, axis=0)))])
        spline = CubicSpline(tau, np.hstack([points, normals]), bc_type="not-a-knot" if len(tau) > 3 else "natural")
        fit = cls(tau, spline, tau)
        fit.s_at_samples = np.concatenate([[0.0], np.cumsum(fit._arc(tau[:-1], tau[1:]))])
        return fit

    def curve(self, tau: np.ndarray, derivative: int = 0) -> np.ndarray:
        """Centreline point (or its derivative) at parameters tau."""
        return self.spline(tau, derivative)[..., :3]

    def normals(self, tau: np.ndarray, derivative: int = 0) -> np.ndarray:
        """Interpolated (not renormalised) surface normal, or its derivative, at parameters tau."""
        return self.spline(tau, derivative)[..., 3:]

    def _arc(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Arc length from lo to hi (arrays of equal shape) by 5-point Gauss-Legendre on the spline speed."""
        half, mid = (hi - lo) / 2.0, (hi + lo) / 2.0
        x = mid[:, None] + half[:, None] * GAUSS_X[None, :]
        speed = np.linalg.norm(self.curve(x, 1), axis=-1)
        return half * (speed @ GAUSS_W)

    def arc_length(self, tau: np.ndarray) -> np.ndarray:
        """Arc length from the start to each parameter value."""
        tau = np.asarray(tau, dtype=float)
        k = np.clip(np.searchsorted(self.tau, tau, side="right") - 1, 0, len(self.tau) - 2)
        return self.s_at_samples[k] + self._arc(self.tau[k], tau)

    @property
    def length(self) -> float:
        return float(self.s_at_samples[-1])

    def parameter_at(self, s: np.ndarray) -> np.ndarray:
        """Chord parameter at arc length s (Newton steps from the linear estimate; |c'| is close to 1)."""
        s = np.asarray(s, dtype=float)
        tau = np.interp(s, self.s_at_samples, self.tau)
        for _ in range(3):
            tau = tau - (self.arc_length(tau) - s) / np.linalg.norm(self.curve(tau, 1), axis=-1)
        return np.clip(tau, self.tau[0], self.tau[-1])

    def frame(self, tau: np.ndarray) -> dict[str, np.ndarray]:
        """Darboux frame and curvatures at parameters `tau`: t, u, n (N, 3) and k_g, k_n, tau_g (N,); also
        k_n_curve = n.c'', the normal curvature read from the centreline's bending alone (the normals' values, not
        their derivative): what a design's curves are judged by where the normals come from a mesh's field."""
        first, d2 = self.spline(tau, 1), self.spline(tau, 2)[:, :3]
        d1, dn = first[:, :3], first[:, 3:]
        speed = _norm(d1)
        t = d1 / speed[:, None]
        raw_n = self.normals(tau)
        along = _dot(raw_n, t)
        n = raw_n - along[:, None] * t
        n_len = _norm(n)
        n /= n_len[:, None]
        u = np.cross(n, t)
        kappa = (d2 - _dot(d2, t)[:, None] * t) / (speed**2)[:, None]
        k_g = _dot(kappa, u)
        # k_n = -t.dn/ds from the normals' first derivative (the second fundamental form), not n.c'': the
        # spline's second derivative is off by ~h^2 k^3 / 12 (3e-8 /mm on the 1 m catenoid at 21 mm samples,
        # which bent its 3.8 m asymptotic strips by 0.02 mm); this is ~1e-10 /mm there.
        k_n = -_dot(dn, t) / (speed * n_len)
        # tau_g = -(dn/ds).u; d(n)/dtau.u = N'.u - (t'.u)(t.N) for n the normalised projection of N.
        dn_u = _dot(dn, u) - k_g * speed * along
        tau_g = -dn_u / (speed * n_len)
        return {"t": t, "u": u, "n": n, "k_g": k_g, "k_n": k_n, "tau_g": tau_g, "k_n_curve": _dot(kappa, n)}

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest points on the sampled centreline to `points` (M, 3): their parameters and distances."""
        return project_onto_curve(self.curve(self.tau), self.tau, points)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def _norm(a: np.ndarray) -> np.ndarray:
    return np.sqrt(_dot(a, a))


@dataclass
class LamellaGeometry:
    """A lamella's arc length, frame and curvatures at its samples, and where its nodes lie along it (mm, 1/mm)."""

    lamella: Lamella
    fit: CurveFit
    s: np.ndarray
    t: np.ndarray
    u: np.ndarray
    n: np.ndarray
    k_g: np.ndarray
    k_n: np.ndarray
    tau_g: np.ndarray
    k_n_curve: np.ndarray
    node_ids: list[str]
    node_s: np.ndarray
    node_tangents: np.ndarray

    @property
    def length(self) -> float:
        return self.fit.length


@dataclass
class NetworkGeometry:
    """The geometry of every lamella of a network in millimetres, and the crossing angle at every node."""

    network: Network
    lamellas: dict[str, LamellaGeometry]
    crossing_angles: dict[str, float]


def lamella_geometry(lamella: Lamella, network: Network) -> LamellaGeometry:
    """Fit, frame and curvatures of one lamella of a millimetre network, with its nodes' arc-length positions."""
    fit = CurveFit.of(lamella.curve, lamella.normals)
    node_xyz = np.array([network.nodes[nid].xyz for nid in lamella.nodes]).reshape(-1, 3)
    node_tau, off = fit.project(node_xyz)
    check_node_stations(lamella, node_tau, off, 1.0, f"lamella {lamella.id}")
    node_s = fit.arc_length(node_tau)
    frame = fit.frame(np.concatenate([fit.tau, node_tau]))
    samples = len(fit.tau)
    tangents = frame["t"][samples:]
    frame = {key: value[:samples] for key, value in frame.items()}
    return LamellaGeometry(lamella, fit, fit.s_at_samples, frame["t"], frame["u"], frame["n"], frame["k_g"],
                           frame["k_n"], frame["tau_g"], frame["k_n_curve"], list(lamella.nodes), node_s, tangents)


def analyse(network: Network) -> NetworkGeometry:
    """Geometry of every lamella (network in mm) and at every node the smallest crossing angle (degrees, 0..90)."""
    network = network.in_mm()
    geometries = {lam.id: lamella_geometry(lam, network) for lam in progress(network.lamellas, "geometry")}
    tangents: dict[str, list[np.ndarray]] = {}
    for geo in geometries.values():
        for nid, t in zip(geo.node_ids, geo.node_tangents):
            tangents.setdefault(nid, []).append(t)
    angles = {}
    for nid, ts in tangents.items():
        if len(ts) >= 2:
            cosines = [abs(float(np.dot(a, b))) for i, a in enumerate(ts) for b in ts[i + 1:]]
            angles[nid] = float(np.degrees(np.arccos(min(1.0, max(cosines)))))
    return NetworkGeometry(network, geometries, angles)


def lamella_table(geometry: NetworkGeometry) -> list[dict]:
    """One row per lamella in display units (m, 1/m, degrees): length, node count, curvature maxima, crossing angles."""
    rows = []
    for lam_id, geo in geometry.lamellas.items():
        angles = [geometry.crossing_angles[n] for n in geo.node_ids if n in geometry.crossing_angles]
        rows.append({
            "lamella": lam_id, "family": geo.lamella.family, "nodes": len(geo.node_ids),
            "length_m": geo.length / 1000.0,
            "max_k_g": float(np.abs(geo.k_g).max() * 1000.0), "max_tau_g": float(np.abs(geo.tau_g).max() * 1000.0),
            "max_k_n": float(np.abs(geo.k_n).max() * 1000.0),
            "min_angle": min(angles) if angles else None, "max_angle": max(angles) if angles else None,
        })
    return rows
