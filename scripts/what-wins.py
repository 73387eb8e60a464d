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
    if key == "speedup" and run.get("verdict_extrapolated"):
        text += ", PT extrapolated"
    return f"{text} at {setting(run)}"


def setting(run):
    rays = f" × {run['recon_rays']} rays" if run.get("recon_rays") else ""
    return f"{run['input_spp']} spp{rays}"


def against_oidn(runs, oidn_runs):
    """The readings against OIDN: the equal-quality speedup where a run lies within OIDN's
    measured curve, and the equal-time PSNR difference against OIDN's best measured run that
    took no longer: the largest among runs with such an OIDN run of at least half their time, else
    the run with the closest budgets (the times are printed). Never an extrapolation."""
    parts = []
    within = best(runs, "speedup_over_oidn")
    if within is not None:
        parts.append(f"{cell(within, 'speedup_over_oidn')} (equal quality)")
    gains = []
    for run in runs:
        cheaper = [o for o in oidn_runs if o["total_s"] <= run["total_s"]]
        if cheaper:
            peer = max(cheaper, key=lambda o: o["psnr_db"])
            close = peer["total_s"] >= 0.5 * run["total_s"]
            ratio = peer["total_s"] / run["total_s"]
            gains.append((close, run["psnr_db"] - peer["psnr_db"] if close else ratio, run, peer))
    if gains:
        _, _, run, peer = max(gains, key=lambda g: (g[0], g[1]))
        gain = run["psnr_db"] - peer["psnr_db"]
        parts.append(f"{gain:+.2f} dB at equal time ({setting(run)} in {run['total_s']:.2f} s against OIDN at "
                     f"{peer['input_spp']} spp in {peer['total_s']:.2f} s)")
    else:
        parts.append("every run faster than OIDN's cheapest")
    return "; ".join(parts)


def main(paths):
    print("| scene, effect | method | best equal-quality speedup over path tracing | against OIDN |")
    print("|---|---|---|---|")
    headlines = []
    for path in paths:
        results = json.load(open(path))
        scene = results["scene"].split("/")[-1]
        bounces = results.get("max_bounces")
        light = "direct light only" if bounces == 1 else f"{bounces} bounces"
        label = f"{scene}, {results['effect']} ({results['width']}×{results['height']}, {light})"
        methods = []
        for run in results["runs"]:
            if run["method"] != "pt" and run["method"] not in methods:
                methods.append(run["method"])
        for method in methods:
            runs = [r for r in results["runs"] if r["method"] == method and r.get("valid", True)]
            oidn_runs = [r for r in results["runs"] if r["method"] == "oidn" and r.get("valid", True)]
            peer = against_oidn(runs, oidn_runs) if method != "oidn" else "—"
            if method != "oidn" and not oidn_runs:
                peer = "OIDN did not run"
            print(f"| {label} | `{method}` | {cell(best(runs, 'speedup'), 'speedup')} | {peer} |")
        for skipped in results.get("skipped", []):
            print(f"| {label} | `{skipped.get('method', skipped)}` | skipped | {skipped.get('reason', '')} |")
        headlines.append(f"- {label}: {results.get('headline', '')}")
    print()
    print("\n".join(headlines))


if __name__ == "__main__":
    main(sys.argv[1:])
