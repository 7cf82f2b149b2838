#!/usr/bin/env python3
"""Move every vertex of a PC2 point cache by a fixed offset from one frame on.

A stand-in for an edit made in Blender, so that `clothdb clip import` can be tried (and the
guide's example run) without Blender:
    scripts/pc2_offset.py clip9/cloth.pc2 --from-frame 5 --mm 0,0,100
PC2 layout (Blender's point cache 2): "POINTCACHE2\\0", int32 version 1, int32 points, float32
start frame, float32 sampling, int32 samples, then samples x points x 3 float32 (little endian).
Python 3 standard library only.
"""

import argparse
import pathlib
import struct
import sys


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", type=pathlib.Path, help="PC2 file, rewritten in place")
    parser.add_argument("--from-frame", type=int, default=0, help="first frame (0-based) moved")
    parser.add_argument("--mm", default="0,0,10", help="offset x,y,z in mm (default 0,0,10)")
    args = parser.parse_args()
    try:
        offset = [float(v) / 1000.0 for v in args.mm.split(",")]
        if len(offset) != 3:
            raise ValueError
    except ValueError:
        sys.exit(f"pc2_offset.py: --mm: expected three numbers x,y,z in mm (got {args.mm!r})")
    data = bytearray(args.file.read_bytes())
    if len(data) < 32 or data[:12] != b"POINTCACHE2\0":
        sys.exit(f"pc2_offset.py: {args.file}: not a PC2 file (no POINTCACHE2 header)")
    _, points, _, _, samples = struct.unpack_from("<iiffi", data, 12)
    if points <= 0 or samples <= 0 or len(data) != 32 + 12 * points * samples:
        sys.exit(f"{args.file}: header says {points} points x {samples} samples, "
                 f"which does not match its {len(data)} bytes")
    if not 0 <= args.from_frame < samples:
        sys.exit(f"pc2_offset.py: --from-frame: {args.from_frame} is outside the cache's 0-{samples - 1}")
    for frame in range(args.from_frame, samples):
        for p in range(points):
            at = 32 + 12 * (frame * points + p)
            x, y, z = struct.unpack_from("<fff", data, at)
            struct.pack_into("<fff", data, at, x + offset[0], y + offset[1], z + offset[2])
    args.file.write_bytes(bytes(data))
    print(f"{args.file}: frames {args.from_frame}-{samples - 1} of {samples} moved by "
          f"({args.mm}) mm, {points} points each")


if __name__ == "__main__":
    main()
