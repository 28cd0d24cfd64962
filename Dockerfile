FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md ./
COPY gateway ./gateway
COPY simulator ./simulator
COPY mappings ./mappings
RUN pip install --no-cache-dir .
EXPOSE 4840 4841 2121 2122 5020 8080
CMD ["cnc-gateway", "run", "mappings/laser-sim.yaml"]
