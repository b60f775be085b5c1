#!/usr/bin/env python3
"""How fast this machine writes one large file from one process and from two (issue 15,
bench/journal/2026-12-03.md, 11:20): the floor under MPI's
strong scaling, which writes one PLY from every rank.

    /usr/bin/python3 bench/write_scaling.py DIR [BYTES]

Writes BYTES (default 1 254 585 762, the sphere800 full-pass PLY) in 4 MiB pwrite calls: from
one process; from two processes into the two halves of one file; from two processes into two
files; and from one process through a shared mmap. Prints the wall time of each.
"""
import mmap
import os
import sys
import time
from multiprocessing import Process

CHUNK = b"x" * (4 << 20)


def pwrite_range(path, offset, size):
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o644)
    done = 0
    while done < size:
        n = min(len(CHUNK), size - done)
        os.pwrite(fd, CHUNK[:n], offset + done)
        done += n
    os.close(fd)


def mmap_write(path, size):
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    os.ftruncate(fd, size)
    m = mmap.mmap(fd, size)
    for at in range(0, size, len(CHUNK)):
        n = min(len(CHUNK), size - at)
        m[at:at + n] = CHUNK[:n]
    m.close()
    os.close(fd)


def timed(name, jobs):
    start = time.perf_counter()
    processes = [Process(target=f, args=a) for f, a in jobs]
    for p in processes:
        p.start()
    for p in processes:
        p.join()
    print(f"{name}: {time.perf_counter() - start:.2f} s")


def main():
    folder = sys.argv[1]
    size = int(sys.argv[2]) if len(sys.argv) > 2 else 1254585762
    half = size // 2
    paths = [os.path.join(folder, f"write_scaling_{k}.bin") for k in range(4)]
    try:
        timed("one process, one file", [(pwrite_range, (paths[0], 0, size))])
        timed("two processes, two halves of one file", [(pwrite_range, (paths[1], 0, half)),
                                                          (pwrite_range, (paths[1], half, size - half))])
        timed("two processes, two files", [(pwrite_range, (paths[2], 0, half)),
                                           (pwrite_range, (paths[3], 0, size - half))])
        for p in paths:
            os.remove(p)
        timed("one process, shared mmap", [(mmap_write, (paths[0], size))])
    finally:
        for p in paths:
            if os.path.exists(p):
                os.remove(p)
    print(f"{size} bytes; load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
