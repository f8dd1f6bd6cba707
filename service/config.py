"""Service settings: one pydantic-settings class, each field from an `SMM_` environment variable."""

from __future__ import annotations

import os
from pathlib import Path

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

from service.manifest import REPO_MODELS_DIR
from service.observability.logs import LogLevel


class Settings(BaseSettings):
    """Every setting of the service; the environment variable is SMM_<FIELD NAME>."""

    # An empty variable (SMM_API_KEY=) counts as unset, not as an empty key.
    model_config = SettingsConfigDict(env_prefix="SMM_", extra="forbid", env_ignore_empty=True)

    models_dir: Path = Field(REPO_MODELS_DIR, description="Directory of <model-id>/ folders.")
    host: str = Field("127.0.0.1", description="Interface uvicorn binds to.")
    port: int = Field(8000, ge=1, le=65535)
    workers: int = Field(
        1,
        ge=1,
        description="Server processes (`smm-serve` only), each loading every model. The "
        "limits below and /metrics are per process; one process already uses every core "
        "through onnxruntime's threads, so more only helps on machines with many cores.",
    )
    max_num_samples: int = Field(
        10_000, ge=1, description="Largest num_samples a request may ask for (413 beyond)."
    )
    max_batch_targets: int = Field(
        64,
        ge=1,
        description="Most targets in one POST /smm/batch (413 beyond). A batch holds one "
        "computation slot for all its targets, so this bounds how long it keeps the slot "
        "from other requests; 64 targets with reference configurations are about 30 KB, "
        "inside max_body_bytes.",
    )
    max_batch_samples: int = Field(
        64_000,
        ge=1,
        description="Largest sum of num_samples over a batch's targets (413 beyond; each "
        "target also within max_num_samples): 64 targets at the bundled models' largest "
        "default (1000 samples), which the slowest of them (iiwa14 position, ~0.4 s a target "
        "on 2 cores) answers within request_deadline_s.",
    )
    batch_threads: int = Field(
        0,
        ge=0,
        description="Threads that answer a POST /smm/batch's targets at once, each target "
        "whole (the flow network and the compiled kernels release the GIL): 0 gives a "
        "batch the process's share of the cores (cores // workers), 1 answers its targets "
        "one after another. Every target's answer is the same either way.",
    )
    malloc_arenas: int = Field(
        2,
        ge=0,
        description="glibc malloc arenas for the whole process (mallopt M_ARENA_MAX, set at "
        "start; 0 keeps glibc's default of 8 per core). Each thread that allocates gets an "
        "arena of its own up to that limit, and memory freed in an arena stays with it: in "
        "an 8-minute soak of mixed requests (python -m tools.soak) the default's RSS rose "
        "from 448 to 709 MiB and kept rising, while 2 arenas held it at 333 to 359 MiB.",
    )
    malloc_mmap_threshold_bytes: int = Field(
        4_194_304,
        ge=0,
        le=33_554_432,
        description="Blocks of at least this size get a mapping of their own, returned to "
        "the system when freed (mallopt M_MMAP_THRESHOLD, set at start; 0 keeps glibc's "
        "default, which starts at 128 KiB and rises to the size of every mapped block "
        "freed, up to 32 MiB, after which a request's large arrays stay in the heap and "
        "RSS swings with what the heap holds). Fixed, the heap serves the same sizes all "
        "along. At 4 MiB an answer's arrays (an iiwa14 pose answer's Jacobians at N = 500 "
        "take 168 KiB) are reused from the heap; below that size each would be mapped, "
        "faulted in page by page and unmapped again on every answer (CHANGELOG).",
    )
    flow_scratch_bytes: int = Field(
        25_165_824,
        ge=0,
        description="Largest scratch block the compiled int8 layers keep between flow calls "
        "(two at most, one per call running at once; service/models/int8_mlp.c). A call "
        "needs about 4.6 kB a row of a 512-wide network (5.1 kB on AVX2), so 24 MiB keeps a "
        "call of up to about 5,400 rows (4,900 on AVX2); a larger call maps its own block "
        "and faults every page of it in again. With 6 MiB (about 1,300 rows), an iiwa14 "
        "pose request at N = 4000 took 18,000 page faults and its server total was 84.5 ms; "
        "with 24 MiB, 1,700 and 60 ms (CHANGELOG). The process holds up to twice this "
        "after large requests; 0 keeps none.",
    )
    row_helper_spin_us: int = Field(
        1000,
        ge=0,
        le=1_000_000,
        description="Microseconds the compiled kernels' row helper threads (the second "
        "thread of a split Newton, self-clearance, roadmap or int8 call; "
        "service/pipeline/row_helper.h) spin for their next part before they sleep, "
        "yielding their core to any other thread. Spinning keeps a request's split calls "
        "from waiting on a core's wake-up; it costs CPU only where a core is otherwise "
        "idle. An iiwa14 pose request at N = 500 arriving 20 ms after the last took "
        "17.6-18.3 ms with 0, 14.5-16.4 ms with 1000 and 13.1-15.0 ms with 4000, at 21-23, "
        "22-26 and 29-33 ms of CPU; 3 ms after the last, 11.8-12.4 ms with any (2-core "
        "Intel Xeon, CHANGELOG). 0: sleep at once, where CPU time is billed or autoscaled "
        "on and matters more than that latency.",
    )
    onnx_threads: int = Field(
        0,
        ge=0,
        description="onnxruntime intra-op threads per session; 0 gives each session the "
        "process's share of the cores (cores // workers): a flow call of at least 384 rows "
        "made while no other runs takes them all, a smaller one or one made beside another "
        "takes one thread (a worker woken for a small call costs more than it saves: "
        "`python -m tools.onnx_threads`), requests in flight at once share the cores (the "
        "workers spin only while a call runs, so an idle one holds no core). "
        "`python -m tools.load` measures the trade against 1 thread (docs/operations.md).",
    )
    compiled_int8: bool = Field(
        True,
        description="Evaluate the int8 flow networks with the compiled layers "
        "(service/models/int8_mlp.py) where the processor has AMX, AVX-512 VNNI or AVX2: the "
        "exact integer product on every processor (onnxruntime's saturates on AVX2 without "
        "VNNI, and a replica there would answer otherwise), in fewer passes over the rows "
        "(`python -m tools.onnx_threads` times both). false, or a processor with none of "
        "them: onnxruntime's session.",
    )
    log_level: LogLevel = Field(
        "info", description="Level of the service's JSON logs and of uvicorn's."
    )

    # Bounded work: whatever clients send, the process holds a bounded amount of it.
    max_body_bytes: int = Field(
        65_536,
        ge=1_024,
        description="Largest request body in bytes (413 beyond); a full POST /smm body with a "
        "reference configuration is well under 1 KiB.",
    )
    max_open_requests: int = Field(
        64,
        ge=1,
        description="Requests being received or answered at once, probes and /metrics "
        "excepted; more get 503 with Retry-After at once. Bounds the memory held by bodies.",
    )
    max_in_flight: int = Field(
        2,
        ge=1,
        description="POST /smm computations running at once. The pipeline is CPU-bound, so "
        "more than the number of cores only stretches every request's latency.",
    )
    max_queued: int = Field(
        8,
        ge=0,
        description="POST /smm requests that may wait for a computation slot; one more gets "
        "503 with Retry-After at once.",
    )
    max_queue_wait_s: float = Field(
        5.0,
        gt=0,
        description="Longest a POST /smm request waits for a computation slot before 503.",
    )
    retry_after_s: int = Field(1, ge=1, description="Retry-After header of a 503, in seconds.")
    request_deadline_s: float = Field(
        30.0,
        gt=0,
        description="Per-request deadline, from when the route takes the request (its body "
        "read and validated), queue wait included: the pipeline stops at its next step past "
        "it and the request gets 504.",
    )
    shutdown_drain_s: float = Field(
        35.0,
        gt=0,
        description="On SIGTERM, how long `smm-serve` waits for requests in flight to finish "
        "(new connections are refused meanwhile); longer than the deadline so none is cut.",
    )

    @property
    def batch_threads_per_request(self) -> int:
        """batch_threads, or the process's share of the cores: cores // workers."""
        if self.batch_threads:
            return self.batch_threads
        return max(1, (os.cpu_count() or 1) // self.workers)

    @property
    def onnx_threads_per_session(self) -> int:
        """onnx_threads, or the process's share of the cores: cores // workers."""
        if self.onnx_threads:
            return self.onnx_threads
        return max(1, (os.cpu_count() or 1) // self.workers)

    api_key: SecretStr | None = Field(
        None,
        description="When set, every route but /healthz, /readyz and /metrics needs it in an "
        "X-API-Key header (or Authorization: Bearer); 401 otherwise.",
    )
