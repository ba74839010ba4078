# One image for every voxshape service; compose.yaml chooses the command.
FROM python:3.11-slim
RUN useradd --create-home --uid 1000 voxshape
WORKDIR /app
COPY pyproject.toml README.md ./
COPY protocol ./protocol
COPY services ./services
RUN pip install --no-cache-dir . && mkdir -p /app/runs && chown voxshape /app/runs
USER voxshape
ENV PYTHONUNBUFFERED=1
CMD ["voxshape", "--help"]
