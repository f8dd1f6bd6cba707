"""The compiled kernels (service/pipeline/native.c, service/models/int8_mlp.c): the one thing
pyproject.toml cannot say.

Everything else about the package is in pyproject.toml. The extension needs a C compiler
and CPython's headers at install time (both come with every CPython build and with the
Dockerfile's build stage), and nothing at run time.
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "service.pipeline._native",
            sources=["service/pipeline/native.c"],
            depends=["service/pipeline/row_helper.h"],
            extra_compile_args=["-O2", "-std=c99", "-fno-fast-math"],
        ),
        # The int8 flow network (service/models/int8_mlp.c): onnxruntime's arithmetic to
        # the bit, so no contraction of a * b + c into one rounding unless written so.
        Extension(
            "service.models._int8_mlp",
            sources=["service/models/int8_mlp.c"],
            depends=["service/pipeline/row_helper.h"],
            extra_compile_args=["-O2", "-std=c99", "-fno-fast-math", "-ffp-contract=off"],
        ),
    ]
)
