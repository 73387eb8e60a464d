"""Denoise one path-traced frame with Intel Open Image Denoise (pyoidn) for lfr's `oidn` method.

argv[1] is a JSON object: {"width", "height", "color", "albedo", "normal", "output", "quality"}, the
image entries being paths of raw little-endian float32 RGB files, row-major from the top-left.
The colour is linear HDR (nonnegative), the albedo in [0, 1], the normals in [-1, 1]; the Rust side
has already sanitised them. The first pyoidn.denoise call is an untimed warm-up (device creation
and weight loading are one-time costs an application amortises); the second, identical call is
timed. The last stdout line is a JSON object: {"seconds", "peak_rss_mb", "oidn_version"}.
"""

import json
import resource
import sys
import time

import numpy as np
import pyoidn


def load(args, name):
    width, height = int(args["width"]), int(args["height"])
    path = args[name]
    values = np.fromfile(path, dtype="<f4")
    expected = width * height * 3
    if values.size != expected:
        raise SystemExit(f"{name} image {path}: expected {expected} float32 values "
                         f"({width}x{height} RGB), found {values.size}")
    return np.ascontiguousarray(values.reshape(height, width, 3), dtype=np.float32)


def oidn_version():
    version = getattr(pyoidn, "version", None)
    for candidate in (getattr(version, "oidn_version", None), getattr(pyoidn, "__version__", None)):
        if isinstance(candidate, str):
            return candidate
    try:
        from importlib.metadata import version as package_version

        return package_version("pyoidn")
    except Exception:
        return None


def main():
    args = json.loads(sys.argv[1])
    color = load(args, "color")
    albedo = load(args, "albedo")
    normal = load(args, "normal")
    quality = args.get("quality", "high")

    def denoise():
        return pyoidn.denoise(color, albedo, normal, hdr=True, quality=quality)

    denoise()  # warm-up: device creation, weight loading, first-use allocations
    start = time.perf_counter()
    output = denoise()
    seconds = time.perf_counter() - start

    np.ascontiguousarray(output, dtype="<f4").tofile(args["output"])

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # ru_maxrss is KiB on Linux and bytes on macOS.
    peak_rss_mb = peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0
    print(json.dumps({"seconds": seconds, "peak_rss_mb": peak_rss_mb, "oidn_version": oidn_version()}))


if __name__ == "__main__":
    main()
