"""The container's HEALTHCHECK: `python -m service.healthcheck` exits 0 if /healthz answers 200.

It finds the server the way the server finds its socket, from the SMM_ settings
(service/config.py), so `docker run -e SMM_PORT=9000` keeps the check pointed at the
server. A server bound to every interface (0.0.0.0, the image's default) is asked on
127.0.0.1. Standard library only, so a check costs one short-lived interpreter.
"""

from __future__ import annotations

import sys
import urllib.request

from service.config import Settings

TIMEOUT_S = 4.0  # under the Dockerfile's HEALTHCHECK --timeout
WILDCARD_HOSTS = frozenset({"0.0.0.0", "::", ""})


def healthz_url(settings: Settings) -> str:
    """The /healthz URL of the server these settings start."""
    host = "127.0.0.1" if settings.host in WILDCARD_HOSTS else settings.host
    if ":" in host:  # an IPv6 literal
        host = f"[{host}]"
    return f"http://{host}:{settings.port}/healthz"


def main() -> int:
    """0 when /healthz answers 200 within TIMEOUT_S, else 1 (the reason on stderr)."""
    url = healthz_url(Settings())
    try:
        with urllib.request.urlopen(url, timeout=TIMEOUT_S) as response:
            status = int(response.status)
    except OSError as error:  # refused, timed out, or an HTTP error status (URLError)
        print(f"unhealthy: GET {url}: {error}", file=sys.stderr)
        return 1
    if status != 200:
        print(f"unhealthy: GET {url} answered {status}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
