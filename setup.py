"""Build hook for the optional compiled kernels (hbench/numerics/_kernels.c); the metadata is in
pyproject.toml. Without a C compiler the build of the extension is skipped (``optional=True``)
and hbench runs its pure-numpy path, which gives the same numbers (see hbench/numerics/kernels.py)."""

import hashlib
from pathlib import Path

from setuptools import Extension, setup

SOURCE = "hbench/numerics/_kernels.c"
# the library records which source it was built from: hbench.numerics.kernels refuses a stale build
DIGEST = hashlib.sha256((Path(__file__).parent / SOURCE).read_bytes()).hexdigest()

setup(
    ext_modules=[
        Extension(
            "hbench.numerics._kernels",
            [SOURCE],
            define_macros=[("HB_SOURCE_SHA256", f'"{DIGEST}"')],
            # no fused multiply-add: the kernels must round exactly as the numpy path does;
            # -O3 vectorises the loops over samples, and without -ffast-math no sum is reordered
            extra_compile_args=["-O3", "-ffp-contract=off", "-fno-fast-math"],
            optional=True,
        )
    ]
)
