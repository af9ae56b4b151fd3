"""Builds the multithreaded C kernels (worker/native/src) as a plain shared library.

The library is loaded with ctypes (worker/native/__init__.py), which releases the GIL for the
duration of each call; OpenMP provides the threads.
"""
from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "worker.native._glintk",
            sources=["worker/native/src/glintk.c"],
            extra_compile_args=["-O3", "-fopenmp", "-fno-math-errno", "-std=c11"],
            extra_link_args=["-fopenmp"],
        )
    ]
)
