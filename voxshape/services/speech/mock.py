"""The mock engine: text in (`Said` messages: a simulated teacher, or `voxshape teach
--through-speech`), text out, with the errors a grammar-restricted recognizer makes. Its core,
which the simulated teacher shares, is the confusion model of voxshape/recognition/; here is
what the speech service adds: its `--confusion` weights."""

from __future__ import annotations

from dataclasses import replace

from voxshape.recognition.confusion import ERROR_KINDS, MockRecognizer, MockSettings
from voxshape.runtime.settings import ConfigError

__all__ = ["MockRecognizer", "MockSettings", "confused", "weights_text"]


def weights_text(settings: MockSettings) -> str:
    """`misheard=0.6,dropped=0.3,inserted=0.1`: the relative weights of the kinds of error."""
    return ",".join(f"{kind}={getattr(settings, kind):g}" for kind in ERROR_KINDS)


def confused(settings: MockSettings, weights: str) -> MockSettings:
    """`settings` with the weights of `misheard=0.6,dropped=0.3,inserted=0.1` (any of them)."""
    try:
        given = {k.strip(): float(v) for k, v in (p.split("=") for p in weights.split(","))}
        unknown = set(given) - set(ERROR_KINDS)
        if unknown:
            raise ValueError(f"unknown kind {sorted(unknown)[0]!r}")
        return replace(settings, **given)
    except ValueError as e:
        raise ConfigError(
            f"mock engine: {e} (e.g. --error-rate 0.2 --confusion "
            "misheard=0.6,dropped=0.3,inserted=0.1 --latency 0.3)"
        ) from None
