"""Builds the multithreaded C kernels (worker/native/src/*.c) as one plain shared library.

Every capability keeps its kernels in a file of its own under worker/native/src (shared inline
helpers in glint_common.h); all of them are linked into worker/native/_glintk*.so, loaded with
ctypes (worker/native/__init__.py), which releases the GIL for the duration of each call;
OpenMP provides the threads.
"""
from glob import glob

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "worker.native._glintk",
            sources=sorted(glob("worker/native/src/*.c")),
            depends=sorted(glob("worker/native/src/*.h")),
            extra_compile_args=["-O3", "-fopenmp", "-fno-math-errno", "-std=c11"],
            extra_link_args=["-fopenmp"],
        )
    ]
)
