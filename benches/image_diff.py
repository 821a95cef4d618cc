#!/usr/bin/env python3
"""How far one render is from another: relative RMS and mean difference of two PFM images.

    python3 benches/image_diff.py BEFORE.pfm AFTER.pfm [--threshold 0.01]

Over the pixels whose grey value (the mean of the channels) in BEFORE is above `threshold`
times BEFORE's largest: the RMS of the difference over the RMS of BEFORE, the difference of
the means, and the largest difference as a share of BEFORE's peak. What docs/performance.md
quotes when a change to the renderer is said to move the images by so much: render one stored
solution to PFM with the build before and the build after (`volrad render --solution s.volrad
-o before.pfm`), then compare. Standard library only.
"""

import argparse
import array
import sys


def read_pfm(path):
    with open(path, "rb") as f:
        magic = f.readline().strip()
        width, height = map(int, f.readline().split())
        scale = float(f.readline())
        channels = {b"PF": 3, b"Pf": 1}.get(magic)
        if channels is None:
            sys.exit(f"{path}: not a PFM file (magic {magic!r})")
        values = array.array("f")
        values.frombytes(f.read(4 * width * height * channels))
    if (scale < 0) != (sys.byteorder == "little"):
        values.byteswap()
    grey = [sum(values[i:i + channels]) / channels for i in range(0, len(values), channels)]
    return width, height, grey


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before")
    parser.add_argument("after")
    parser.add_argument("--threshold", type=float, default=0.01,
                        help="pixels above this share of BEFORE's peak (default 0.01)")
    args = parser.parse_args()
    w0, h0, a = read_pfm(args.before)
    w1, h1, b = read_pfm(args.after)
    if (w0, h0) != (w1, h1):
        sys.exit(f"sizes differ: {w0}×{h0} against {w1}×{h1}")
    peak = max(a)
    pairs = [(x, y) for x, y in zip(a, b) if x > args.threshold * peak]
    if not pairs or peak <= 0:
        sys.exit("no pixel above the threshold")
    n = len(pairs)
    rms = (sum((y - x) ** 2 for x, y in pairs) / sum(x * x for x, _ in pairs)) ** 0.5
    mean = sum(y for _, y in pairs) / sum(x for x, _ in pairs) - 1
    largest = max(abs(y - x) for x, y in pairs) / peak
    print(f"{n} pixels above {args.threshold:g} of the peak: RMS {100 * rms:.3f} %, "
          f"mean {100 * mean:+.3f} %, largest {100 * largest:.3f} % of the peak")


if __name__ == "__main__":
    main()
