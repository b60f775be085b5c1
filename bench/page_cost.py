#!/usr/bin/env python3
"""What a fresh page costs on this machine (bench/README.md "4 December 2026"; docs/mesher.md
"Memory pages"): faults in MIB MiB of new anonymous memory, one write per 4 KiB page, in 4 KiB
pages and then advised MADV_HUGEPAGE (2 MiB pages), each ROUNDS times, once straight after the
last run and once after PAUSE seconds (a virtual machine's balloon may hand freed memory back to
the host, which backs it again on the next touch).
    bench/page_cost.py [MIB] [ROUNDS] [PAUSE]"""
import mmap
import sys
import time

import numpy as np


def touch(size, huge):
    m = mmap.mmap(-1, size, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    if huge:
        m.madvise(mmap.MADV_HUGEPAGE)
    t = time.perf_counter()
    np.frombuffer(m, dtype=np.uint8)[::4096] = 1
    t = time.perf_counter() - t
    m.close()
    return t


def main():
    mib = int(sys.argv[1]) if len(sys.argv) > 1 else 1024
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    pause = float(sys.argv[3]) if len(sys.argv) > 3 else 5.0
    size = mib << 20
    with open("/sys/kernel/mm/transparent_hugepage/enabled") as f:
        print(f"THP: {f.read().strip()}; {mib} MiB per run")
    print("| pages | after | ms | us per 4 KiB |\n|---|---|--:|--:|")
    for _ in range(rounds):
        for huge in (False, True):
            for wait in (pause, 0.0):
                time.sleep(wait)
                t = touch(size, huge)
                print(f"| {'2 MiB' if huge else '4 KiB'} | {'%g s pause' % wait if wait else 'the last run'} "
                      f"| {1e3 * t:.1f} | {1e6 * t / (size / 4096):.2f} |")


if __name__ == "__main__":
    main()
