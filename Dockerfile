# The SMM service: FastAPI + onnxruntime and the bundled models. No torch, no build tools,
# no pip (nor its cache) in the final image; runs as uid:gid 10001:10001. Every setting is
# an SMM_ environment variable (service/config.py), e.g. docker run -e SMM_WORKERS=2.
# Nothing is written at run time (the bytecode is compiled at build; the service writes
# no file), so it runs on a read-only root file system with no writable volume, as the
# Kubernetes pod of deploy/ does.
# tools/container_test (python -m tools.container_test) builds and runs this file (.ci/run
# runs it).

# Build stage: the service and its run-time dependencies, at the versions of
# constraints.txt (the README's install uses the same file), into a venv, with the
# compiled kernels (service/pipeline/native.c) built by the C compiler this stage alone
# installs (the final image has no compiler; the extension needs none to run); then pip and
# setuptools leave the venv, and so do the dependencies' own test suites (65 MB). The
# bytecode is compiled again, checked by the source's hash instead of its mtime: a copy
# that rounds mtimes to the second (buildah's COPY --from does) would otherwise leave half
# the modules to be compiled at every start, since a read-only image cannot cache them.
FROM python:3.11-slim AS build
# The compiler's version is the base image's Debian release's: it builds the C extensions and
# stays in this stage.
# hadolint ignore=DL3008
RUN apt-get update \
    && apt-get install --yes --no-install-recommends gcc libc6-dev \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY constraints.txt pyproject.toml setup.py README.md ./
COPY service ./service
RUN python -m venv /opt/venv \
    && /opt/venv/bin/pip install --no-cache-dir --disable-pip-version-check \
        --constraint constraints.txt . \
    && /opt/venv/bin/pip uninstall --yes --disable-pip-version-check pip setuptools \
    && find /opt/venv -depth -type d -name tests -exec rm -rf {} + \
    && /opt/venv/bin/python -m compileall -q -f -j 0 --invalidation-mode checked-hash /opt/venv/lib \
    && /opt/venv/bin/python -c "import importlib.util as u; assert u.find_spec('torch') is None"

# Final stage: the base image, the venv and the models; nothing else from the build.
FROM python:3.11-slim
# uid and gid 10001, fixed: a Kubernetes pod names them (runAsUser, runAsGroup) in
# deploy/base/deployment.yaml, which also runs the image on a read-only root file system.
RUN groupadd --system --gid 10001 smm \
    && useradd --system --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin smm
COPY --from=build /opt/venv /opt/venv
WORKDIR /app
# Root-owned and read-only to the service; their sha256 is checked against the manifests
# at start-up, and /readyz answers 503 naming any model that fails.
COPY models ./models
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    SMM_MODELS_DIR=/app/models \
    SMM_HOST=0.0.0.0 \
    SMM_PORT=8000
USER 10001:10001
EXPOSE 8000
# Asks /healthz on SMM_PORT, so a port set at `docker run` keeps the check right.
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-m", "service.healthcheck"]
# smm-serve: uvicorn with SMM_PORT, SMM_WORKERS, one JSON access log (uvicorn's own is off)
# and a graceful shutdown that drains requests in flight for SMM_SHUTDOWN_DRAIN_S.
CMD ["smm-serve"]
