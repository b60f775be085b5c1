#!/usr/bin/python3
"""Writes a sphere-like uint8 scan N^3 (default 1024) as `sphere_NxNxN_uint8.raw` for the
loader benchmark (bench/README.md "Loading a dense scan"): a blurred ball of radius 0.4 N (200 inside,
20 outside, tanh edge of 2 voxels) with deterministic noise of +-3, written slab by slab so the
whole array is never in memory."""
import sys
import numpy as np


def main():
    out = sys.argv[1]
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 1024
    c, r = (n - 1) / 2.0, 0.4 * n
    y, x = np.mgrid[0:n, 0:n].astype(np.float32)
    rng = np.random.default_rng(15)
    with open(out, "wb") as f:
        for z in range(n):
            d = np.sqrt((x - c) ** 2 + (y - c) ** 2 + np.float32((z - c) ** 2)) - r
            v = 110.0 - 90.0 * np.tanh(d / 2.0) + rng.integers(-3, 4, size=(n, n))
            f.write(np.clip(np.rint(v), 0, 255).astype(np.uint8).tobytes())


if __name__ == "__main__":
    main()
