"""The container test: build the Dockerfile with buildah, run the image's own command, check it.

    sudo .venv/bin/python -m tools.container_test        # .ci/run runs this (as root)

What it checks, over HTTP on 127.0.0.1 against the image's CMD (run with
`buildah run --isolation chroot`, which shares the host's network):

- GET /healthz answers 200; GET /readyz answers 200 and lists every model bundled in
  models/, each loaded and verified (sha256 against its manifest) at start-up;
- POST /smm for every bundled model: every returned configuration reaches the target
  within the requested tolerance by a forward kinematics independent of the image (the
  references in training/evaluate/references/: the planar 3R's closed form, the iiwa14's
  DH table, the Panda's URDF read in float64), lies within the joint limits, and the
  configuration the target was made from is close to an answer;
- settings reach the process from the environment (`docker run -e`): SMM_PORT,
  SMM_API_KEY (401 without the key, 200 with it) and SMM_MAX_NUM_SAMPLES (413 beyond);
- one access-log line per request, the service's JSON one, none from uvicorn;
- the image's HEALTHCHECK command exits 0 while the server runs, non-zero once it stopped;
- the server process runs as the image's non-root USER;
- the image holds no torch, no pip, no compiler, no pip or apt download cache, and /app
  holds the models only;
- SIGTERM stops the server gracefully (the app's "shut down" log line);
- then the image once more as the Kubernetes pod runs it (deploy/base/deployment.yaml: its
  env, a read-only root file system and no writable volume, not even /tmp): a write to /
  fails with EROFS even as root; the server's / is mounted read-only; the service's
  imports find current bytecode in /opt/venv (none compiled at each start); /readyz 200
  with every model; a checked POST /smm per model; the peak RSS with every computation
  slot busy at SMM_MAX_NUM_SAMPLES stays under the pod's memory limit; SIGTERM drains.

Figures, printed and written to docs/container.json (docs/deployment.md quotes them): the
image size (and its base's), the cold start (server process start to /readyz answering 200),
the read-only run's RSS (ready, and peak) and the time of each step.

The base image is the real python:3.11-slim when a registry answers; otherwise a stand-in
built with debootstrap from the Debian mirror (bookworm: Python 3.11), cached as a tarball
under ~/.cache/smm-ci so that later runs skip debootstrap. Everything happens in a private
buildah store (vfs driver, chroot isolation) in a temporary directory that is removed at
the end, with the containers and images in it. Needs root, buildah and, for the
stand-in, debootstrap (.ci/run installs both).

The modules, by job: buildah (the buildah wrapper and the stand-in base image), targets
(a request per bundled model and its independent answer check), image (what the image
holds), processes (the server's processes seen from the host), http_checks (the checks
over HTTP), server_checks (the image's CMD run as built), read_only (the run as the pod
runs it), report (the figures written), __main__ (the command line and the steps).
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIGURES = ROOT / "docs" / "container.json"
