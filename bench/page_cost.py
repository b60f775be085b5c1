#!/usr/bin/env python3
"""What a fresh page costs on this machine (bench/journal/2026-12-04.md, 05:50
and 23:43; docs/mesher.md "Memory pages"): faults in MIB MiB of new anonymous memory, one write per
4 KiB page, in 4 KiB pages and then advised MADV_HUGEPAGE (2 MiB pages), by one thread and by
THREADS threads (each its own MIB / THREADS, at once), each ROUNDS times, once straight after the
last run and once after PAUSE seconds (a virtual machine's balloon may hand freed memory back to
the host, which backs it again on the next touch). The ratio of the two rows' times is how far
faulting in fresh memory scales with threads, which bounds a whole run's thread scaling.
    bench/page_cost.py [MIB] [ROUNDS] [PAUSE] [THREADS]"""
import concurrent.futures
import mmap
import os
import sys
import time

import numpy as np


def touch(size, huge, threads):
    maps = [mmap.mmap(-1, size // threads, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS) for _ in range(threads)]
    for m in maps:
        if huge:
            m.madvise(mmap.MADV_HUGEPAGE)
    arrays = [np.frombuffer(m, dtype=np.uint8) for m in maps]

    def write(a):  # numpy lets go of the GIL for the strided store
        a[::4096] = 1

    with concurrent.futures.ThreadPoolExecutor(threads) as pool:
        t = time.perf_counter()
        list(pool.map(write, arrays))
        t = time.perf_counter() - t
    del arrays
    for m in maps:
        m.close()
    return t


def main():
    mib = int(sys.argv[1]) if len(sys.argv) > 1 else 1024
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    pause = float(sys.argv[3]) if len(sys.argv) > 3 else 5.0
    threads = int(sys.argv[4]) if len(sys.argv) > 4 else os.cpu_count()
    size = mib << 20
    with open("/sys/kernel/mm/transparent_hugepage/enabled") as f:
        print(f"THP: {f.read().strip()}; {mib} MiB per run")
    print("| pages | after | threads | ms | us per 4 KiB | GB/s |\n|---|---|--:|--:|--:|--:|")
    for _ in range(rounds):
        for huge in (False, True):
            for wait in (pause, 0.0):
                for n in sorted({1, threads}):
                    time.sleep(wait)
                    t = touch(size, huge, n)
                    print(f"| {'2 MiB' if huge else '4 KiB'} | {'%g s pause' % wait if wait else 'the last run'} | {n} "
                          f"| {1e3 * t:.1f} | {1e6 * t / (size / 4096):.2f} | {size / t / 1e9:.2f} |", flush=True)


if __name__ == "__main__":
    main()
