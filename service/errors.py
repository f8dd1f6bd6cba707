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


class RequestFieldErrors(SmmError):
    """Several request fields invalid for the chosen model (422), reported together (the
    targets of a batch: one bad target does not hide the others' errors)."""

    status_code = 422

    def __init__(self, errors: list[RequestFieldError]) -> None:
        super().__init__("; ".join(error.message for error in errors))
        self.errors = errors


class LimitExceededError(SmmError):
    """A request asks for more work than the configured limit (413)."""

    status_code = 413


class ModelVerificationError(Exception):
    """A model directory failed verification at start-up; the message names the file."""


class OverloadedError(SmmError):
    """Every computation slot is taken and the wait is full or too long (503 + Retry-After)."""

    status_code = 503

    def __init__(self, message: str, retry_after_s: int, reason: str) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s
        self.reason = reason  # "queue_full" or "queue_timeout", for the metrics


class DeadlineExceededError(SmmError):
    """The request ran past its deadline; the pipeline stopped at its next step (504)."""

    status_code = 504

    def __init__(self, stage: str, budget_s: float) -> None:
        super().__init__(
            f"the request ran past its deadline of {budget_s:g} s (SMM_REQUEST_DEADLINE_S) "
            f"during stage {stage!r}; ask for fewer num_samples or retry later"
        )
        self.stage = stage


class ModelUnavailableError(SmmError):
    """The requested model failed verification at start-up and is not served (503)."""

    status_code = 503
