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
executor. While no request comes, the services are asked only every ``idle_ticks`` ticks (a
take per service per tick was a twentieth of the filter's CPU, for nothing): the first request
after a quiet spell is answered at most that many ticks later, and every tick serves again
until the services are quiet once more.
"""

from __future__ import annotations

from typing import Any

from rclpy.service import Service

from audio2pose_ros.ros.diagnosed_node import DiagnosedNode

__all__ = ["RequestBudget"]


class RequestBudget:
    """Serves a node's services itself, at most ``per_tick`` requests per :meth:`serve`."""

    def __init__(self, per_tick: int, idle_ticks: int = 1) -> None:
        """At most ``per_tick`` requests per tick; the services asked every ``idle_ticks`` ticks.

        Both at least 1; ``idle_ticks`` applies while no request comes.
        """
        if per_tick < 1:
            raise ValueError(f"a request budget needs at least 1 request per tick, got {per_tick}")
        if idle_ticks < 1:
            raise ValueError(f"a request budget asks at least every tick, got {idle_ticks}")
        self.per_tick = per_tick
        self.idle_ticks = idle_ticks
        self.services: list[Service[Any, Any]] = []
        self.served_total = 0
        self.most_in_a_tick = 0  # the largest number served by one serve()
        self.polls = 0  # serve() calls that asked the services
        self._turn = 0  # the service asked first at the next serve()
        self._quiet_ticks = 0  # ticks since the services were last asked, while quiet

    def adopt_services(self, node: DiagnosedNode) -> None:
        """Serve every service ``node`` has now (rclpy's parameter services) from :meth:`serve`."""
        self.services = list(node.services)
        node.withhold_services(self.services)

    def serve(self) -> None:
        """A tick: take and answer up to ``per_tick`` waiting requests, the services in turn.

        While the services are quiet, only every ``idle_ticks``-th call asks them.
        """
        if self._quiet_ticks:
            self._quiet_ticks = (self._quiet_ticks + 1) % self.idle_ticks
            return
        self.polls += 1
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
        self._quiet_ticks = 0 if served else 1 % self.idle_ticks


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
