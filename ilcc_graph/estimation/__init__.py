"""The estimation core: one problem description, one solver, one noise policy, thin strategies.

- ``problem``: boards, views, ties (plain data); ``keys``: variable keys.
- ``graphs``: helpers that each return a ``NonlinearFactorGraph``; ``Assembly`` of a problem.
- ``solver``: input checks, kernel table, Levenberg-Marquardt, the marginals wrapper.
- ``noise``: gate, variance components, final factor (``solve_problem``).
- strategies: ``batch`` (one data set), ``sessions`` (several, rigid or drift, range offset),
  ``rig`` (several cameras), ``incremental`` (iSAM2), ``paper`` (the paper's refinement).
"""

from ilcc_graph.estimation.batch import BatchSolution, solve
from ilcc_graph.estimation.noise import BoardStats, NoiseOptions, Solution, solve_problem
from ilcc_graph.estimation.problem import BoardPrior, Problem, Tie, View, frames_problem
from ilcc_graph.estimation.solver import KERNELS, SolverOptions

__all__ = [
    "KERNELS",
    "BatchSolution",
    "BoardPrior",
    "BoardStats",
    "NoiseOptions",
    "Problem",
    "Solution",
    "SolverOptions",
    "Tie",
    "View",
    "frames_problem",
    "solve",
    "solve_problem",
]
