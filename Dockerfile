# The compiled readers (validation's gateway/jobs/validation/_plain.c and the OPC UA source's
# gateway/sources/_publish.c, built by setup.py) need a C compiler, which the image that runs the gateway
# does without: the wheel is built in a stage of its own, and the build fails if a reader is not in it
# (setup.py marks the extensions optional for installs elsewhere).
FROM python:3.11-slim AS build
RUN apt-get update && apt-get install -y --no-install-recommends gcc libc6-dev \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY pyproject.toml setup.py README.md ./
COPY gateway ./gateway
COPY simulator ./simulator
RUN pip wheel --no-cache-dir --no-deps --wheel-dir /wheels . \
    && python -c "import glob, sys, zipfile; \
names = zipfile.ZipFile(glob.glob('/wheels/*.whl')[0]).namelist(); \
sys.exit(0 if all(any(m in n for n in names) for m in ('validation/_plain', 'sources/_publish')) \
    else 'the wheel lacks a compiled reader')"

FROM python:3.11-slim
WORKDIR /app
COPY --from=build /wheels /wheels
RUN pip install --no-cache-dir /wheels/*.whl && rm -rf /wheels
COPY mappings ./mappings
EXPOSE 4840 4841 2121 2122 5000 5020 8080
CMD ["cnc-gateway", "run", "mappings/laser-sim.yaml"]
