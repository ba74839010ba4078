"""Codec cost per message type: encoded size, encode and decode time (strict validation
included in both). Prints a table; figures are medians of repeated timings in one run.

    .venv/bin/python benchmarks/codec.py
"""

from __future__ import annotations

import statistics
import timeit

from voxshape.protocol import decode, encode
from voxshape.protocol.examples import example_messages

N = 500  # calls per timing


def main() -> None:
    print(f"{'type':<12} {'bytes':>6} {'encode us':>10} {'decode us':>10}")
    for _, message in example_messages("bench"):
        data = encode(message)
        enc = statistics.median(timeit.repeat(lambda m=message: encode(m), number=N, repeat=7))
        dec = statistics.median(timeit.repeat(lambda d=data: decode(d), number=N, repeat=7))
        print(f"{message.TYPE:<12} {len(data):>6} {enc / N * 1e6:>10.1f} {dec / N * 1e6:>10.1f}")


if __name__ == "__main__":
    main()
