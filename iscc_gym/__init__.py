"""iscc-gym: learned resource allocation for integrated sensing, communication and control.

The closed loop of Li et al., "Closed-Loop Integrated Sensing, Communication, and Control for
Efficient Drone Flight", as pure batched numpy functions (``channel``, ``fbl``, ``sensing``,
``dynamics``, ``kalman``, ``stability``, ``trajectory``, ``loop``) around one frozen
:class:`Scenario`.
"""

from .scenario import SCENARIOS, Scenario, make_scenario

__all__ = ["Scenario", "SCENARIOS", "make_scenario"]
__version__ = "0.1.0"
