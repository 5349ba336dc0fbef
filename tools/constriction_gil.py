"""Does constriction's range decoder release the GIL? (It decides whether attribute chunks could
be range-decoded in parallel threads.) A Python thread spins while the main thread decodes 20M
symbols; its progress during the decode is compared with its progress in as long a time after.

    python tools/constriction_gil.py
"""

from __future__ import annotations

import importlib.metadata
import threading
import time

import constriction
import numpy as np


def main(num_symbols: int = 20_000_000) -> None:
    rng = np.random.default_rng(0)
    probs = rng.random(256)
    probs /= probs.sum()
    model = constriction.stream.model.Categorical(probs, perfect=False)
    symbols = rng.choice(256, size=num_symbols, p=probs).astype(np.int32)
    enc = constriction.stream.queue.RangeEncoder()
    enc.encode(symbols, model)
    words = enc.get_compressed()

    def decode():
        return constriction.stream.queue.RangeDecoder(words).decode(model, num_symbols)

    t = time.perf_counter()
    assert np.array_equal(decode(), symbols)
    alone = time.perf_counter() - t
    count, stop = [0], [False]

    def spin():
        while not stop[0]:
            count[0] += 1

    spinner = threading.Thread(target=spin)
    spinner.start()
    time.sleep(0.2)
    c0, t = count[0], time.perf_counter()
    decode()
    during = time.perf_counter() - t
    c1 = count[0]
    time.sleep(during)
    c2 = count[0]
    stop[0] = True
    spinner.join()
    print(f"constriction {importlib.metadata.version('constriction')}: "
          f"decode of {num_symbols:,} symbols {alone:.2f} s alone, {during:.2f} s beside a spinning thread; "
          f"the spinner advanced {c1 - c0:,} during the decode and {c2 - c1:,} in as long after "
          f"({(c1 - c0) / max(c2 - c1, 1):.1%}): the GIL is {'held' if c1 - c0 < 0.2 * (c2 - c1) else 'released'}")


if __name__ == "__main__":
    main()
