#!/usr/bin/env python3
"""Translated copies of a particle set, one a frame: a moving sequence for benchmarks
(scripts/bench_sequence.sh, issue #20).

    scripts/make_moving_particles.py data/plume.ply 'out/plume.####.ply' --frames 24 \
        --velocity 0.5,0,0.2

Frame f (1..N) is the input moved by f * velocity (world units a frame). Reads and writes
binary little-endian PLY with float/double vertex properties (the bundled plume's format),
or ASCII PLY; every other property is copied unchanged.
"""
import argparse
import re
import struct
import sys

TYPES = {"float": "f", "float32": "f", "double": "d", "float64": "d", "int": "i", "int32": "i",
         "uint": "I", "uint32": "I", "uchar": "B", "uint8": "B", "char": "b", "int8": "b",
         "short": "h", "int16": "h", "ushort": "H", "uint16": "H"}


def read_header(data):
    end = data.index(b"end_header") + len(b"end_header")
    end = data.index(b"\n", end) + 1
    lines = data[:end].decode("ascii").splitlines()
    fmt, count, props, in_vertex = None, 0, [], False
    for line in lines:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            in_vertex = words[1] == "vertex"
            if in_vertex:
                count = int(words[2])
        elif words[0] == "property" and in_vertex:
            if words[1] == "list":
                sys.exit("error: list properties in the vertex element are not supported")
            props.append((words[2], TYPES[words[1]]))
    return data[:end], fmt, count, props, end


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("input")
    ap.add_argument("pattern", help="output name with #### for the frame")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--velocity", default="0.5,0,0", help="X,Y,Z world units a frame")
    args = ap.parse_args()
    velocity = [float(v) for v in args.velocity.split(",")]
    m = re.search(r"#+", args.pattern)
    if not m:
        sys.exit("error: the output name needs a #### frame pattern")
    data = open(args.input, "rb").read()
    header, fmt, count, props, start = read_header(data)
    names = [p[0] for p in props]
    axes = [names.index(a) for a in ("x", "y", "z")]
    if fmt == "binary_little_endian":
        layout = "<" + "".join(p[1] for p in props)
        rows = list(struct.iter_unpack(layout, data[start:start + count * struct.calcsize(layout)]))
    elif fmt == "ascii":
        text = data[start:].decode("ascii").split("\n")[:count]
        rows = [[float(w) if props[i][1] in "fd" else int(w) for i, w in enumerate(line.split())] for line in text]
    else:
        sys.exit(f"error: PLY format {fmt} is not supported (binary_little_endian or ascii)")
    for f in range(1, args.frames + 1):
        moved = []
        for row in rows:
            row = list(row)
            for k, a in enumerate(axes):
                row[a] += f * velocity[k]
            moved.append(row)
        name = args.pattern[:m.start()] + str(f).zfill(m.end() - m.start()) + args.pattern[m.end():]
        with open(name, "wb") as out:
            out.write(header)
            if fmt == "binary_little_endian":
                out.write(b"".join(struct.pack(layout, *row) for row in moved))
            else:
                out.write("".join(" ".join(str(v) for v in row) + "\n" for row in moved).encode("ascii"))


if __name__ == "__main__":
    main()
