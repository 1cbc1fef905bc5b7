"""A Frame on OpenSees (openseespy): elasticBeamColumn elements on corotational (or, for the linear solve the buckling
eigenproblem starts from, linear) transformations, stiff beam links, zeroLength scissor hinges, tension-only trusses for
the cables; a static solve (Newton, load steps) of the initial strains and a load case together."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabline.analysis.frame import Frame
from fabline.analysis.stiffness import HINGE_STIFFNESS, LINK_STIFFNESS
from fabline.analysis.strains import fixed_end_forces, strain_loads
from fabline.errors import FablineError

STEPS = 2
RETRY_STEPS = 8                 # a case that does not converge from the last one's state: from the start in 8 steps
TOLERANCE = 1e-8                # displacement increment norm, mm
MAX_ITERATIONS = 60
INSTALL = ("analysis needs openseespy: pip install 'fabline[analysis]'; on Debian its wheel also needs the system BLAS "
           "(apt-get install libblas3)")


def opensees():
    """The openseespy module, or one line saying how to get it."""
    try:
        import openseespy.opensees as ops
    except (ImportError, RuntimeError) as error:
        raise FablineError(f"{INSTALL} ({error})") from None
    return ops


def _square_to(axis: np.ndarray) -> np.ndarray:
    """A unit vector square to `axis` (for an element's orientation)."""
    other = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 * np.linalg.norm(axis) else [0.0, 1.0, 0.0])
    return other / np.linalg.norm(other)


@dataclass
class Solution:
    """A solved case: node displacements and rotations (N, 6), support reactions (node index -> 6), each beam's forces
    in the basic order (N, Mz_i, Mz_j, My_i, My_j, T) with the locked-in strain, each cable's tension (N)."""

    displacements: np.ndarray
    reactions: dict[int, np.ndarray]
    beam_forces: np.ndarray
    cable_forces: np.ndarray
    converged: bool


class Model:
    """One Frame built in OpenSees; `solve` runs a case on it from the unstressed start. `linear`: small-displacement
    beams (Linear transformations), for the prebuckling forces of a linear buckling analysis."""

    def __init__(self, frame: Frame, linear: bool = False):
        self.frame = frame
        self.ops = ops = opensees()
        ops.wipe()
        ops.model("basic", "-ndm", 3, "-ndf", 6)
        for k, p in enumerate(frame.xyz):
            ops.node(k + 1, *map(float, p))
        for k, flags in frame.supports.items():
            ops.fix(k + 1, *flags)
        sec = frame.section
        axes = frame.axes()
        for e, (i, j) in enumerate(frame.beams):
            ops.geomTransf("Linear" if linear else "Corotational", e + 1, *map(float, axes[e, 2]))
            ops.element("elasticBeamColumn", e + 1, int(i) + 1, int(j) + 1, sec.A, sec.E, sec.G, sec.J,
                        sec.I_strong, sec.I_weak, e + 1)
        tag = len(frame.beams)
        for master, slave in frame.links:  # washers: short beams LINK_STIFFNESS times the strip's (no constraint
            tag += 1                         # equations: OpenSees's transformation handler is slow with thousands)
            ops.geomTransf("Linear", tag, *map(float, _square_to(frame.xyz[slave] - frame.xyz[master])))
            ops.element("elasticBeamColumn", tag, int(master) + 1, int(slave) + 1, sec.A, LINK_STIFFNESS * sec.E,
                        LINK_STIFFNESS * sec.G, sec.I_strong, sec.I_strong, sec.I_strong, tag)
        self.hinge_tags = []
        if frame.hinges:
            ops.uniaxialMaterial("Elastic", 1, HINGE_STIFFNESS[0])
            ops.uniaxialMaterial("Elastic", 2, HINGE_STIFFNESS[1])
        for a, b, axis in frame.hinges:
            tag += 1
            other = _square_to(axis)
            ops.element("zeroLength", tag, int(a) + 1, int(b) + 1, "-mat", 1, 1, 1, 2, 2, "-dir", 1, 2, 3, 5, 6,
                        "-orient", *map(float, axis), *map(float, other))
            self.hinge_tags.append(tag)
        self.cable_tags = []
        if len(frame.cables):
            ops.uniaxialMaterial("Elastic", 3, frame.cable_E, 0.0, 0.0)  # no stiffness in compression
            ops.uniaxialMaterial("InitStrainMaterial", 4, 3, frame.cable_prestrain)
        for i, j in frame.cables:
            tag += 1
            ops.element("Truss", tag, int(i) + 1, int(j) + 1, frame.cable_area, 4)
            self.cable_tags.append(tag)
        self.strain_loads = strain_loads(frame)
        self.fixed_end = fixed_end_forces(frame)
        self.free = [k + 1 for k in range(len(frame.xyz)) if k not in frame.supports]

    def _apply(self, loads: np.ndarray, residual: bool, steps: int = STEPS) -> bool:
        ops = self.ops
        ops.wipeAnalysis()
        ops.reset()
        ops.remove("loadPattern", 1)
        ops.remove("timeSeries", 1)
        ops.timeSeries("Linear", 1)
        ops.pattern("Plain", 1, 1)
        total = loads + (self.strain_loads if residual else 0.0)
        for k in np.flatnonzero(np.abs(total).max(axis=1) > 0.0):
            ops.load(int(k) + 1, *map(float, total[k]))
        ops.constraints("Plain")
        ops.numberer("RCM")
        try:
            ops.system("Mumps")    # the same solution as UMFPACK, about 3x faster on the pavilion's 18792 DOFs
        except Exception:          # an OpenSees built without MUMPS (openseespy raises its own bare error type)
            ops.system("UmfPack")
        ops.test("NormDispIncr", TOLERANCE, MAX_ITERATIONS)
        ops.algorithm("Newton")
        ops.integrator("LoadControl", 1.0 / steps)
        ops.analysis("Static")
        return ops.analyze(steps) == 0

    def solve(self, loads: np.ndarray, residual: bool = True) -> Solution:
        """The frame under `loads` (N, 6: forces N, moments N mm, global axes) and, with `residual`, the initial
        strains, from the unstressed start."""
        return self._read(self._apply(loads, residual), residual)

    def _read(self, converged: bool, residual: bool) -> Solution:
        ops = self.ops
        ops.reactions()
        n = len(self.frame.xyz)
        displacements = np.array([ops.nodeDisp(k + 1) for k in range(n)])
        reactions = {k: np.array(ops.nodeReaction(k + 1)) for k in self.frame.supports}
        forces = np.array([ops.eleResponse(e + 1, "basicForce") for e in range(len(self.frame.beams))]).reshape(-1, 6)
        if residual:
            forces = forces + self.fixed_end
        cables = np.array([ops.eleResponse(tag, "axialForce")[0] for tag in self.cable_tags]) if self.cable_tags else np.zeros(0)
        return Solution(displacements, reactions, forces, cables, converged)

    def next_case(self, loads: np.ndarray, residual: bool = True) -> Solution:
        """Another case after `solve`, from the last one's equilibrium (the frame is elastic, so the path does not
        matter, and Newton starts close)."""
        ops = self.ops
        ops.remove("loadPattern", 1)
        ops.pattern("Plain", 1, 1)  # the linear time series stands at 1 after `solve`
        total = loads + (self.strain_loads if residual else 0.0)
        for node in np.flatnonzero(np.abs(total).max(axis=1) > 0.0):
            ops.load(int(node) + 1, *map(float, total[node]))
        ops.integrator("LoadControl", 0.0)
        if ops.analyze(1) == 0:
            return self._read(True, residual)
        return self._read(self._apply(loads, residual, RETRY_STEPS), residual)  # from the start, in smaller steps
