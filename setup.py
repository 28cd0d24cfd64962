"""The one compiled module: G-code validation's plain-block reader (gateway/jobs/validation/_plain.c).

Everything else is in pyproject.toml. The extension is optional: where no C compiler
is available the install still succeeds and validation uses the pure-Python reader
(same verdicts, about thirty times slower on large programs).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "gateway.jobs.validation._plain",
            ["gateway/jobs/validation/_plain.c"],
            # No fused multiply-add: Python rounds a*b+c twice, and the estimates must agree to the bit.
            extra_compile_args=["-O2", "-ffp-contract=off", "-fno-fast-math"],
            optional=True,
        )
    ]
)
