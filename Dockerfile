# The splitspec image: one image for every role (orchestrator, plant, agent, router).
#   docker build -t splitspec .
#   docker run --rm splitspec design examples/paper_discrete.yaml
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    RERUN_ANALYTICS=0

WORKDIR /app
COPY pyproject.toml README.md LICENSE ./
COPY splitspec_core ./splitspec_core
COPY agents ./agents
COPY plant ./plant
COPY orchestrator ./orchestrator
COPY examples ./examples

# the same install step as docs/how-to/several_machines.md ("Starting the processes by hand")
RUN python -m pip install .

ENTRYPOINT ["splitspec"]
CMD ["--help"]
