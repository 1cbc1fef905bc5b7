"""Registration of measured node positions onto the design: rigid best fit, on all or on chosen nodes."""

from __future__ import annotations

import numpy as np

from fabline.errors import FablineError


def rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising sum |R source + t - target|^2 (Kabsch, no reflection)."""
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((target - target_mean).T @ (source - source_mean))
    d = np.sign(np.linalg.det(u @ vt))
    rotation = u @ np.diag([1.0, 1.0, d]) @ vt
    return rotation, target_mean - rotation @ source_mean


def register(measured: np.ndarray, design: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Best rigid fit of measured onto design positions using the nodes flagged in `reference`.

    Returns R, t and the RMS distance over the reference nodes; needs three that are not collinear.
    """
    source, target = measured[reference], design[reference]
    if len(source) < 3 or np.linalg.matrix_rank(source - source.mean(axis=0), tol=1e-6 * max(np.ptp(source), 1.0)) < 2:
        raise FablineError(f"registration needs at least 3 measured reference nodes not on one line, got {len(source)}")
    rotation, translation = rigid_fit(source, target)
    rms = float(np.sqrt(np.mean(np.sum((source @ rotation.T + translation - target) ** 2, axis=1))))
    return rotation, translation, rms
