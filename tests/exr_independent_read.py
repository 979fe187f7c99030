#!/usr/bin/env python3
"""Read a sweptvol depth EXR with the reference OpenEXR library and print a JSON summary.

An independent check of the files `src/io/exr_depth.rs` writes. Needs the PyPI packages
`OpenEXR` (3.x) and `numpy`:

    python3 -m venv /tmp/exrvenv && /tmp/exrvenv/bin/pip install OpenEXR numpy
    /tmp/exrvenv/bin/python tests/exr_independent_read.py part.depth-xmin.exr

Output keys: channels (names, sorted), dtypes (numpy dtype per channel), width, height,
z_min / z_max (over finite Z, world units; null if none), inf_count (pixels with Z = +inf),
z_bits (every Z as its float32 bit pattern, row-major from the top row, so a comparison is exact
and keeps infinities), meta (the `sweptvol:meta` JSON text), attributes (the other `sweptvol:*`
header attributes: text as str, doubles as float; OpenEXR itself gives doubles as numpy arrays of
shape (1,)).
"""

import json
import sys

import numpy as np
import OpenEXR


def plain(value):
    """A header value as JSON-friendly data. OpenEXR 3.x gives text attributes as str and
    double attributes as numpy arrays of shape (1,)."""
    if isinstance(value, bytes):
        return value.decode("latin-1")
    if isinstance(value, np.ndarray):
        return value.item() if value.size == 1 else value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def summarize(path):
    # Closing the file empties its header dict, so read everything inside the `with`.
    with OpenEXR.File(path, separate_channels=True) as exr:
        header = exr.header()
        channels = {name: np.array(c.pixels) for name, c in exr.channels().items()}
        meta = plain(header["sweptvol:meta"])
        attributes = {
            name: plain(value)
            for name, value in sorted(header.items())
            if name.startswith("sweptvol:") and name != "sweptvol:meta"
        }
    z = channels["Z"]
    finite = z[np.isfinite(z)]
    return {
        "channels": sorted(channels),
        "dtypes": {name: str(pixels.dtype) for name, pixels in sorted(channels.items())},
        "width": int(z.shape[1]),
        "height": int(z.shape[0]),
        "z_min": float(finite.min()) if finite.size else None,
        "z_max": float(finite.max()) if finite.size else None,
        "inf_count": int(np.isposinf(z).sum()),
        "z_bits": z.astype(np.float32).view(np.uint32).ravel().tolist(),
        "meta": meta,
        "attributes": attributes,
    }


def main():
    if len(sys.argv) != 2:
        sys.exit(f"usage: {sys.argv[0]} FILE.exr")
    print(json.dumps(summarize(sys.argv[1]), indent=2))


if __name__ == "__main__":
    main()
