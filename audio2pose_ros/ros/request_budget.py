"""A node's services served from its tick, a few requests per tick, so requests never starve it.

A storm of set_parameters requests (a script in a loop, a slider, an attacker) keeps a
parameter service busy. An executor serves every request it is handed: rclpy's
SingleThreadedExecutor one per round beside each ready timer, so on a loaded machine, where the
node gets a fraction of a core, every round paid for a request besides the tick and the command
timer slowed to a fraction of its rate (commands stopped for hundreds of milliseconds); rclpy's
EventsExecutor all of those waiting, back to back, whatever the node's callback groups say.

:class:`RequestBudget` therefore keeps the node's services from its executor
(:meth:`~audio2pose_ros.ros.diagnosed_node.DiagnosedNode.withhold_services`) and serves them
itself: :meth:`RequestBudget.serve`, which the node calls at each tick, takes and answers at
most ``per_tick`` waiting requests, the services taking turns. The others wait in the
middleware's queue (rclpy's parameter services keep the newest 1000), so a request costs at most
a few per cent of a tick period and a storm delays answers, never commands, under either
executor.
"""

from __future__ import annotations

from typing import Any

from rclpy.service import Service

from audio2pose_ros.ros.diagnosed_node import DiagnosedNode

__all__ = ["RequestBudget"]


class RequestBudget:
    """Serves a node's services itself, at most ``per_tick`` requests per :meth:`serve`."""

    def __init__(self, per_tick: int) -> None:
        """A budget of ``per_tick`` requests (at least 1) per tick."""
        if per_tick < 1:
            raise ValueError(f"a request budget needs at least 1 request per tick, got {per_tick}")
        self.per_tick = per_tick
        self.services: list[Service[Any, Any]] = []
        self.served_total = 0
        self.most_in_a_tick = 0  # the largest number served by one serve()
        self._turn = 0  # the service asked first at the next serve()

    def adopt_services(self, node: DiagnosedNode) -> None:
        """Serve every service ``node`` has now (rclpy's parameter services) from :meth:`serve`."""
        self.services = list(node.services)
        node.withhold_services(self.services)

    def serve(self) -> None:
        """A tick: take and answer up to ``per_tick`` waiting requests, the services in turn."""
        served = misses = 0
        while served < self.per_tick and misses < len(self.services):
            service = self.services[self._turn]
            self._turn = (self._turn + 1) % len(self.services)
            if _serve_one(service):
                served, misses = served + 1, 0
            else:
                misses += 1
        self.served_total += served
        self.most_in_a_tick = max(self.most_in_a_tick, served)


def _serve_one(service: Service[Any, Any]) -> bool:
    """Take one waiting request of ``service`` and send its answer; False when none waits."""
    with service.handle:
        taken: tuple[Any, Any] | None = service.handle.service_take_request(
            service.srv_type.Request
        )
    if taken is None:
        return False
    request, header = taken  # what rclpy's executors unpack, whatever the stub says
    if request is None or header is None:
        return False
    service.send_response(service.callback(request, service.srv_type.Response()), header)
    return True
