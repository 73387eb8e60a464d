"""Mean HDR-FLIP of several test images against one reference, for lfr's metrics.

argv[1] is a JSON object: {"width", "height", "reference", "tests": [...]}, the images being paths
of raw little-endian float32 linear RGB files, row-major from the top-left. Non-finite values are
replaced by 0 and negative ones clamped to 0, since HDR-FLIP expects nonnegative linear input.
The last stdout line is a JSON object: {"mean_errors": [...]} in the order of "tests".
"""

import json
import sys

import flip_evaluator
import numpy as np


def load(path, width, height):
    values = np.fromfile(path, dtype="<f4")
    expected = width * height * 3
    if values.size != expected:
        raise SystemExit(f"image {path}: expected {expected} float32 values "
                         f"({width}x{height} RGB), found {values.size}")
    image = values.reshape(height, width, 3).astype(np.float32)
    image = np.nan_to_num(image, nan=0.0, posinf=0.0, neginf=0.0)
    return np.ascontiguousarray(np.maximum(image, 0.0), dtype=np.float32)


def main():
    args = json.loads(sys.argv[1])
    width, height = int(args["width"]), int(args["height"])
    reference = load(args["reference"], width, height)
    if not np.any(reference > 0.0):
        # FLIP derives its exposure range from the reference's luminance; for an all-black
        # reference the range is empty and the library aborts the process.
        raise SystemExit("HDR-FLIP is undefined for an all-black reference: FLIP derives its "
                         "exposure range from the reference luminance")
    errors = []
    for path in args["tests"]:
        test = load(path, width, height)
        _, mean_error, _ = flip_evaluator.evaluate(reference, test, "HDR", inputsRGB=True,
                                                   applyMagma=False, computeMeanError=True)
        errors.append(float(mean_error))
    print(json.dumps({"mean_errors": errors}))


if __name__ == "__main__":
    main()
