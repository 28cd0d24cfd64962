"""The compiled modules, both optional fast paths with pure-Python twins that give the same results:

* gateway/jobs/validation/_plain.c: G-code validation's plain-block reader (about thirty
  times faster than the pure-Python reader on large programs);
* gateway/sources/opcua/_publish.c: the OPC UA source's PublishResponse reader for data changes
  (asyncua's own decoding does the rest, and all of it where this is not built).

Everything else is in pyproject.toml. Where no C compiler is available the install still
succeeds and the pure-Python paths do the work.
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
        ),
        Extension(
            "gateway.sources.opcua._publish",
            ["gateway/sources/opcua/_publish.c"],
            extra_compile_args=["-O2", "-Wall", "-Wextra"],
            optional=True,
        ),
    ]
)
