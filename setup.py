"""The compiled kernels (service/pipeline/native.c): the one thing pyproject.toml cannot say.

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
            extra_compile_args=["-O2", "-std=c99", "-fno-fast-math"],
        )
    ]
)
