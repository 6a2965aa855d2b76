"""Initial values: the absolute pose by UPnP and the corner order across frames."""

from ilcc_graph.init.correspondence import OrderOptions, OrderResult, bearing_errors, resolve_half_turns
from ilcc_graph.init.upnp import UpnpSolution, object_space_cost, refine_angular, upnp

__all__ = [
    "OrderOptions",
    "OrderResult",
    "UpnpSolution",
    "bearing_errors",
    "object_space_cost",
    "refine_angular",
    "resolve_half_turns",
    "upnp",
]
