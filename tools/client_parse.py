"""What a client's reading of answers costs: the wire models' parse of POST /smm answers,
kept as a planner keeps them.

    python -m tools.client_parse --model iiwa14-pose --targets 64 \
        [--out docs/benchmark/client-parse.json]

Answers the targets in process (the evaluation's held-out targets, uniform configurations
in the limits and their FK, seed 7; target i with seed i, at the model's served default),
encodes each answer as the server does, then parses them one after another with
`SmmResponse.model_validate_json`, keeping every parsed answer (a client holding a
batch's answers, or a planner's along a path), and reports the CPU per answer, mean over
the targets, parsed into:

- `tuples`: the wire models as they are (an answer's configurations are tuples);
- `lists`: the same models with every configuration a list (`ListComponentOut`),

each with the cyclic garbage collector on (a client as it runs) and off (the parse
alone). A tuple of floats leaves the collector's view the first time a collection sees
it; a list stays in it, and every later full collection scans it again, so the cost of
lists grows with the answers a client keeps. Compare figures only within one run.
"""

from __future__ import annotations

import argparse
import gc
import json
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from pydantic import BaseModel, create_model

from service.api.answers import encode
from service.api.smm import query_for_model, smm_fields
from service.manifest import REPO_MODELS_DIR, bundled_model_ids
from service.models.registry import ServedModel, load_model
from service.pipeline.run import run
from service.wire import ComponentOut, SmmRequest, SmmResponse
from tools.batch_benchmark import target_of
from training.evaluate.targets import uniform_configurations
from training.machine import Machine

# ComponentOut with every configuration a list: what the tuples are measured against.
ListComponentOut = create_model(
    "ListComponentOut",
    __base__=ComponentOut,
    representative=(list[float], ...),
    configurations=(list[list[float]], ...),
    joint_min=(list[float], ...),
    joint_max=(list[float], ...),
    nearest_to_reference=(list[float] | None, ...),
    path=(list[list[float]] | None, ...),
    safest_configuration=(list[float] | None, ...),
)
ListSmmResponse = create_model(
    "ListSmmResponse", __base__=SmmResponse, components=(list[ListComponentOut], ...)
)


PARSERS: dict[str, type[BaseModel]] = {"tuples": SmmResponse, "lists": ListSmmResponse}


def answers_of(model: ServedModel, targets: int, seed: int = 7) -> list[bytes]:
    """The encoded POST /smm answers of `targets` held-out targets, target i with seed i."""
    manifest = model.manifest
    bodies = []
    for i, q in enumerate(uniform_configurations(model.limits, targets, seed)):
        request = SmmRequest.model_validate(
            {
                "robot": manifest.robot,
                "task": manifest.task.name,
                "target": target_of(model, q),
                "seed": i,
            }
        )
        query = query_for_model(request, model)
        bodies.append(encode(smm_fields(model, query, run(model, query))))
    return bodies


@contextmanager
def collector(on: bool) -> Iterator[None]:
    """The cyclic garbage collector on or off while the block runs, as it was after."""
    was = gc.isenabled()
    gc.enable() if on else gc.disable()
    try:
        yield
    finally:
        gc.enable() if was else gc.disable()


def parse_cpu_ms(bodies: Sequence[bytes], parser: type[BaseModel], collect: bool) -> float:
    """Mean CPU ms per answer of parsing every body with `parser`, keeping every answer,
    the collector on (`collect`) or off; a full collection first, so each run starts alike."""
    kept: list[BaseModel] = []
    gc.collect()
    with collector(collect):
        start_s = time.process_time()
        for body in bodies:
            kept.append(parser.model_validate_json(body))
        spent_s = time.process_time() - start_s
    return spent_s * 1e3 / max(len(bodies), 1)


def measure(bodies: Sequence[bytes], repeats: int = 3) -> dict[str, Any]:
    """Least CPU ms per answer over `repeats`, per parser, the collector on and off."""
    figures: dict[str, Any] = {
        "answers": len(bodies),
        "mean_answer_bytes": sum(map(len, bodies)) / max(len(bodies), 1),
    }
    for name, parser in PARSERS.items():
        for collect in (True, False):
            key = f"{name}_{'collector_on' if collect else 'collector_off'}_ms"
            figures[key] = min(parse_cpu_ms(bodies, parser, collect) for _ in range(repeats))
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    bundled = bundled_model_ids()
    parser.add_argument("--model", required=True, choices=bundled)
    parser.add_argument("--targets", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None, help="write the figures there as JSON")
    args = parser.parse_args()
    machine = Machine.now()
    model = load_model(REPO_MODELS_DIR / args.model, threads=1)
    figures = measure(answers_of(model, args.targets), args.repeats)
    figures["model"] = model.reference
    figures["machine"] = machine.ended().as_json()
    figures["command"] = (
        f"python -m tools.client_parse --model {args.model} --targets {args.targets} "
        f"--repeats {args.repeats}"
    )
    print(json.dumps(figures, indent=1))
    if args.out is not None:
        args.out.write_text(json.dumps(figures, indent=1) + "\n")
    print(
        f"{args.model}, {args.targets} answers of {figures['mean_answer_bytes'] / 1e3:.0f} kB "
        f"kept: CPU per answer {figures['tuples_collector_on_ms']:.2f} ms parsed as tuples, "
        f"{figures['lists_collector_on_ms']:.2f} ms as lists (collector off: "
        f"{figures['tuples_collector_off_ms']:.2f} and {figures['lists_collector_off_ms']:.2f})"
        f" ({Machine.from_json(figures['machine']).describe()})"
    )


if __name__ == "__main__":
    main()
