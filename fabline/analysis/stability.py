"""Whether the gridshell's frame buckles: under the erection's residual stress alone (refused below a factor of 1, naming
where and what to change) and under each load case on top of it, by the linear buckling eigenproblem
(`fabline.analysis.buckling`) on the axial forces of OpenSees's linear solves."""

from __future__ import annotations

import dataclasses

import numpy as np

from fabline.analysis.buckling import Buckling, buckling as linear_buckling
from fabline.analysis.frame import Frame
from fabline.analysis.model import GridshellFrame
from fabline.analysis.solve import Model, Solution
from fabline.errors import FablineError


def rounded(factor: float) -> float | None:
    """A buckling factor for the record: None where there is none (the load only stiffens the frame)."""
    return round(float(factor), 4) if np.isfinite(factor) else None


def taut(solution: Solution) -> np.ndarray:
    """The cables in tension in a solved state (a slack one braces nothing)."""
    return solution.cable_forces > 0.0


def erection_stability(frame: Frame) -> Buckling:
    """The linear buckling factor of the erection's residual stress alone (the axial forces of OpenSees's linear solve
    of the strain loads): a frame under 1 would buckle as it is erected, so no load case has an equilibrium to find,
    and this is refused naming where and what to change (with cables pretensioned: the pretension it stands with), as
    are supports that leave the shell free to move as a rigid body."""
    free = frame.rigid_motions()
    if free:
        supports = sorted(frame.names[k].split("/")[0] for k in frame.supports)
        raise FablineError(f"analysis: the supports ({len(supports)}: {', '.join(supports[:6])}"
                           f"{', ...' if len(supports) > 6 else ''}) leave the shell {free} rigid-body motion(s) "
                           f"(pinned supports on one line let it turn about that line): mark more nodes of kind "
                           f"'support', off that line, or analyse with fixed supports")
    zero = np.zeros((len(frame.xyz), 6))
    state = Model(frame, linear=True).solve(zero)
    axial = state.beam_forces[:, 0]
    result = linear_buckling(frame, axial, cable_taut=taut(state))
    if result.factor > 1.0:
        return result
    squeezed = int(np.argmin(axial))
    strip, beam = frame.beam_tags[squeezed] if frame.beam_tags else ("beam", squeezed)
    said = (f"analysis: the erected shell does not stand in this frame: the erection's own stresses are "
            f"{1.0 / result.factor:.2f} times its buckling load (factor {result.factor:.3f}; the mode largest at "
            f"{frame.names[result.peak()]}; strip {strip} beam {beam} carries {-axial[squeezed] / 1000.0:.2f} kN of "
            f"compression), so no load case has an equilibrium")
    if len(frame.cables) and frame.cable_prestrain > 0.0 and taut(state).any():
        loose = Model(dataclasses.replace(frame, cable_prestrain=0.0), linear=True).solve(zero).beam_forces[:, 0]
        without = linear_buckling(frame, loose, cable_taut=taut(state)).factor
        pull = f"the cables' pretension ({1000.0 * frame.cable_prestrain:g} mm/m: {state.cable_forces.max() / 1000.0:.2f} kN)"
        if without > 1.0:
            limit = linear_buckling(frame, axial - loose, base_axial=loose, cable_taut=taut(state)).factor
            raise FablineError(f"{said}: {pull} compresses the strips (without it the factor is {without:.2f}): cut "
                               f"the cables for a pretension under {1000.0 * frame.cable_prestrain * limit:.2f} mm/m "
                               f"(unroll's cable_pretension) or couple the pairs")
        said += f"; without {pull} the factor is {without:.2f}"
    raise FablineError(f"{said}: couple the pairs near {frame.names[result.peak()]}, add supports or a stiffer profile")


def case_buckling(grid: GridshellFrame, cases: dict[str, np.ndarray]) -> dict:
    """Each load case's linear buckling factor about the residual state (the axial forces the case adds to the
    residual's in OpenSees's linear solve, on the residual state's stiffness: a classical linear buckling analysis
    per combination, so that a case Newton could not solve still says whether it buckles), and the lowest one's mode."""
    frame = grid.frame
    model = Model(frame, linear=True)
    base = model.solve(cases["residual"])
    factors, lowest = {}, None
    for name, loads in cases.items():
        if name == "residual":
            continue
        result = linear_buckling(frame, model.next_case(loads).beam_forces[:, 0] - base.beam_forces[:, 0],
                                 base_axial=base.beam_forces[:, 0], cable_taut=taut(base))
        factors[name] = rounded(result.factor)
        if lowest is None or result.factor < lowest[1].factor:
            lowest = name, result
    name, result = lowest
    shape = np.linalg.norm(result.mode[:, :3], axis=1)
    return {"case": name, "factor": rounded(result.factor), "factors": factors,
            "mode_peak_node": frame.names[result.peak()],
            "mode": dict(zip(grid.joints, np.round(shape[list(grid.joints.values())], 4).tolist()))}
