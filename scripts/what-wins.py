#!/usr/bin/env python3
"""The README's "What wins where" table from `lfr compare` results.json files (schema
lfr-compare/3): per comparison, each method's best equal-quality speedup over path tracing and
over OIDN (each read within that comparison; the range is over its repeated timings), and the
headline (the winner at each time budget). Usage: what-wins.py RESULTS.json..."""
import json
import sys


def best(runs, key):
    readings = [r for r in runs if r.get(key) is not None]
    if not readings:
        return None
    return max(readings, key=lambda r: r[key])


def cell(run, key):
    if run is None:
        return "—"
    text = f"{run[key]:.2f}×"
    spread = run.get(key + "_range")
    if spread:
        text += f" ({spread[0]:.2f}–{spread[1]:.2f})"
    rays = f", {run['recon_rays']} rays" if run.get("recon_rays") else ""
    return f"{text} at {run['input_spp']} spp{rays}"


def main(paths):
    print("| scene, effect | method | speedup over path tracing | speedup over OIDN |")
    print("|---|---|---|---|")
    headlines = []
    for path in paths:
        results = json.load(open(path))
        scene = results["scene"].split("/")[-1]
        label = f"{scene}, {results['effect']} ({results['width']}×{results['height']})"
        methods = []
        for run in results["runs"]:
            if run["method"] != "pt" and run["method"] not in methods:
                methods.append(run["method"])
        for method in methods:
            runs = [r for r in results["runs"] if r["method"] == method and r.get("valid", True)]
            print(f"| {label} | `{method}` | {cell(best(runs, 'speedup'), 'speedup')} | "
                  f"{cell(best(runs, 'speedup_over_oidn'), 'speedup_over_oidn') if method != 'oidn' else '1'} |")
        for skipped in results.get("skipped", []):
            print(f"| {label} | `{skipped.get('method', skipped)}` | skipped | {skipped.get('reason', '')} |")
        headlines.append(f"- {label}: {results.get('headline', '')}")
    print()
    print("\n".join(headlines))


if __name__ == "__main__":
    main(sys.argv[1:])
