"""Factor kinds of the assembled graph, one file each (``base.FactorKind``), registered in graph order.

The assembly builds every registered kind once per problem and asks each in turn for its factors,
its variables, their dimensions and start values. A new kind is its own file here and one import
line below (its ``@register`` puts it in ``KINDS``).
"""

from ilcc_graph.estimation.kinds import (  # noqa: F401 - the registry: each import registers its kind
    board_prior,
    board_returns,
    camera_views,
    intrinsics_prior,
    lidar_boards,
    lidar_prior,
    offset_prior,
    ties,
)
from ilcc_graph.estimation.kinds.base import KINDS, FactorKind, Scales, Term, register

__all__ = ["KINDS", "FactorKind", "Scales", "Term", "register"]
