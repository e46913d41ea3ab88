#!/usr/bin/env python3
"""The node's memory bandwidth as 1, 2, 4, 8 and 16 processes see it together: the ceiling of
docs/performance.md, "A model of the time per iteration" (an iteration streams every factor).

    python3 tools/perf/bandwidth.py [PROCESSES ...] > OUT/bandwidth.json

Each process copies an array of 256 MB into another (far larger than any cache) five times
after one warm-up, all of them started together at a barrier; the bandwidth counts each copy's
bytes read and written (2 x 8 B an element, as STREAM's copy does). Needs numpy.
"""
import json
import multiprocessing as mp
import sys
import time

ELEMENTS = 32 * 1024 * 1024
REPEATS = 5


def copy_loop(barrier, results):
    import numpy as np

    a = np.zeros(ELEMENTS)
    b = np.ones(ELEMENTS)
    np.copyto(a, b)
    barrier.wait()
    start = time.perf_counter()
    for _ in range(REPEATS):
        np.copyto(a, b)
    results.put(time.perf_counter() - start)


def measure(processes: int) -> dict:
    barrier = mp.Barrier(processes)
    results = mp.Queue()
    workers = [mp.Process(target=copy_loop, args=(barrier, results)) for _ in range(processes)]
    for w in workers:
        w.start()
    times = [results.get(timeout=300) for _ in workers]
    for w in workers:
        w.join()
    moved = processes * REPEATS * ELEMENTS * 16
    # the slowest process bounds the aggregate: all ran from the same barrier
    return {"processes": processes, "gb_per_s": moved / max(times) / 1e9,
            "per_process_gb_per_s": ELEMENTS * 16 * REPEATS / max(times) / 1e9}


def main() -> None:
    counts = [int(x) for x in sys.argv[1:]] or [1, 2, 4, 8, 16]
    rows = [measure(p) for p in counts]
    for r in rows:
        print(f"{r['processes']:>3} processes: {r['gb_per_s']:7.1f} GB/s together, "
              f"{r['per_process_gb_per_s']:6.1f} each", file=sys.stderr)
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
