"""A node's services served at most a few requests per tick, so requests never starve the tick.

rclpy's SingleThreadedExecutor serves, in each round, every ready timer, subscription and
service once; a storm of set_parameters requests (a script in a loop, a slider, an attacker)
keeps the parameter service ready in every round. On a loaded machine, where the node gets a
fraction of a core, every round then pays for a request besides the tick, and the command timer
slowed to a fraction of its rate: commands stopped for hundreds of milliseconds.

:class:`RequestBudget` is a callback group (rclpy's extension point for "may this callback run
now") for the node's services: it admits at most ``per_tick`` requests between two calls of
:meth:`RequestBudget.renew`, which the node makes at each tick. Once the budget is spent, the
executor leaves the services out of its wait set until the next tick; their requests wait in
the middleware's queue (rclpy's parameter services keep the newest 1000), so a request costs at
most a few per cent of a tick period and a storm delays answers, never commands.
"""

from __future__ import annotations

from typing import Any

from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node

__all__ = ["RequestBudget"]


class RequestBudget(CallbackGroup):
    """Admits at most ``per_tick`` service requests between two :meth:`renew` calls."""

    def __init__(self, per_tick: int) -> None:
        """A budget of ``per_tick`` requests (at least 1) per tick."""
        super().__init__()
        if per_tick < 1:
            raise ValueError(f"a request budget needs at least 1 request per tick, got {per_tick}")
        self.per_tick = per_tick
        self.served = 0  # requests admitted since the last renew
        self.served_total = 0
        self.most_in_a_tick = 0  # the largest number admitted between two renews

    def adopt_services(self, node: Node) -> None:
        """Put every service ``node`` has now (rclpy's parameter services) under this budget."""
        for service in node.services:
            service.callback_group = self
            self.add_entity(service)

    def can_execute(self, entity: Any) -> bool:
        """Whether a request may be served now (else its service waits for the next tick)."""
        return self.served < self.per_tick

    def beginning_execution(self, entity: Any) -> bool:
        """Admit one request if the budget allows it."""
        if self.served >= self.per_tick:
            return False
        self.served += 1
        self.served_total += 1
        self.most_in_a_tick = max(self.most_in_a_tick, self.served)
        return True

    def ending_execution(self, entity: Any) -> None:
        """Nothing to release: requests run one at a time in the node's executor."""

    def renew(self) -> None:
        """A tick: the next ``per_tick`` requests may be served."""
        self.served = 0
