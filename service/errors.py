"""Domain exceptions. `service.main` maps each to an HTTP status; messages list valid choices."""

from __future__ import annotations


class SmmError(Exception):
    """Base of every error the service reports to a client."""

    status_code = 400


class UnknownModelError(SmmError):
    """No served model for the requested robot or task (404); the message lists what is served."""

    status_code = 404

    def __init__(self, robot: str, task: str, served: list[tuple[str, str]]) -> None:
        robots = sorted({r for r, _ in served})
        if robot not in robots:
            message = f"unknown robot {robot!r}; served robots: {', '.join(robots) or 'none'}"
        else:
            tasks = sorted(t for r, t in served if r == robot)
            message = f"unknown task {task!r} for robot {robot!r}; served tasks: {', '.join(tasks)}"
        super().__init__(message)
        self.field = "robot" if robot not in robots else "task"


class RequestFieldError(SmmError):
    """A request field that is well-formed JSON but invalid for the chosen model (422)."""

    status_code = 422

    def __init__(self, location: tuple[str | int, ...], message: str) -> None:
        super().__init__(message)
        self.location = location
        self.message = message


class LimitExceededError(SmmError):
    """A request asks for more work than the configured limit (413)."""

    status_code = 413


class ModelVerificationError(Exception):
    """A model directory failed verification at start-up; the message names the file."""
