"""The routes and their dependencies run on the event loop: every route's endpoint and
every dependency is a coroutine function, so FastAPI takes no thread-pool hop for them (it
runs a plain `def` endpoint or dependency in its thread pool, once per request); the
pipeline alone goes to a worker thread (`compute_in_slot`)."""

from __future__ import annotations

import inspect
from collections.abc import Iterator

from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute

from service.api import health, metrics, robots, self_motion, smm, smm_batch


def dependencies(dependant: Dependant) -> Iterator[Dependant]:
    for dependency in dependant.dependencies:
        yield dependency
        yield from dependencies(dependency)


def test_every_route_and_dependency_is_a_coroutine_function() -> None:
    routers = (smm.router, smm_batch.router, self_motion.router, robots.router, health.router)
    routes = [
        route
        for router in (*routers, metrics.router)
        for route in router.routes
        if isinstance(route, APIRoute)
    ]
    checked = 0
    for route in routes:
        assert inspect.iscoroutinefunction(route.endpoint), route.path
        for dependency in dependencies(route.dependant):
            assert inspect.iscoroutinefunction(dependency.call), (route.path, dependency.call)
            checked += 1
    assert {"/smm", "/smm/batch", "/smm/self-motion"} <= {route.path for route in routes}
    assert checked >= 4  # the registry, settings, admission and metrics of POST /smm
