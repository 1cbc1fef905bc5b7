"""The assembly plan (issue 28): prefabricated segments, the order the strips go in, and a printable sheet per lamella.

Reads the network model and the unroll stage's parts; only the jobs and the command line import it.
"""

from fabline.assembly.plan import AssemblyPlan, plan_assembly

__all__ = ["AssemblyPlan", "plan_assembly"]
