#!/usr/bin/env python3
"""Markdown tables from `lfr compare` results for the docs (standard library only).

    python3 tools/compare_table.py DIR/results.json [--metric psnr|mse8|relmse|time] [--methods a,b,...]

One row per method, one column per input spp. `mse8` is the MSE of the tone-mapped image on the
0-255 scale (the paper's Figure 8 unit): 255^2 * 10^(-PSNR/10). `time` is the run's total seconds
(trace + preprocess + reconstruction). A doc tool only: nothing in the build or the tests needs it.
"""

import json
import sys


def value(run, metric):
    if metric == "psnr":
        return f"{run['psnr_db']:.2f}"
    if metric == "mse8":
        return f"{255.0 ** 2 * 10.0 ** (-run['psnr_db'] / 10.0):.1f}"
    if metric == "relmse":
        return f"{run['rel_mse']:.2e}"
    if metric == "time":
        return f"{run['total_s']:.3f}"
    raise SystemExit(f"unknown metric {metric}")


def main(argv):
    args = list(argv[1:])
    metric, methods = "psnr", None
    if "--metric" in args:
        i = args.index("--metric")
        metric = args[i + 1]
        del args[i : i + 2]
    if "--methods" in args:
        i = args.index("--methods")
        methods = args[i + 1].split(",")
        del args[i : i + 2]
    if len(args) != 1:
        raise SystemExit(__doc__)
    results = json.load(open(args[0]))
    runs = [r for r in results["runs"] if r["method"] != "pt"]
    spps = sorted({r["input_spp"] for r in runs})
    order = methods or list(dict.fromkeys(r["method"] for r in runs))
    print("| method | " + " | ".join(f"{s} spp" for s in spps) + " |")
    print("|---|" + "---|" * len(spps))
    for method in order:
        cells = []
        for spp in spps:
            match = [r for r in runs if r["method"] == method and r["input_spp"] == spp]
            cells.append(value(match[0], metric) if match else "")
        print(f"| {method} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(sys.argv)
