#!/usr/bin/env python3
"""Independent-renderer validation: the Mitsuba Cornell box rendered by Mitsuba 3.

Two subcommands:

  render   Render the Cornell box with Mitsuba 3 in P independent passes and write an
           EXR with the per-pixel mean (R, G, B) and the per-pixel variance of that mean
           (variance.R, variance.G, variance.B), estimated from the spread between passes.
           A JSON with timings and versions is written beside it (FILE.json).

  compare  Per-pixel z-test of our tracer's EXR against such a reference.

Scene (matches what our tracer is expected to render; see README.md):
  * meshes from $LFR_SCENES/cornell-box-mitsuba/meshes (default: <repo>/../shared/scenes),
    referenced in place, never copied or modified;
  * camera of fragments/base.xml: perspective, fov 39.3077 deg on the smaller axis,
    look-at origin (278,273,-800) -> target (278,273,-799), up (0,1,0), box pixel filter;
  * path tracer with unlimited depth (max_depth = -1), independent sampler;
  * materials of fragments/bsdfs-rgb.xml, EXCEPT both boxes use the `white` BSDF
    (0.885809, 0.698859, 0.666422) instead of the purple `box` test value;
  * luminaire mesh translated by -0.5 in y, diffuse `light` BSDF, and a one-sided area
    emitter with radiance (18.387, 10.9873, 2.75357) (it emits along the mesh normal,
    which points down, -y).

Pixel orientation: Mitsuba's image has pixel (0,0) at the top-left and image-right along
forward x up (= -x here), exactly our convention, so the red wall (x ~ 550) is on the LEFT.
No flip is applied; `render` re-checks this on every run (see `orientation_check` in the JSON).
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[2]

# Scene constants (from cbox-rgb.xml and its fragments).
CAMERA = dict(origin=[278.0, 273.0, -800.0], target=[278.0, 273.0, -799.0], up=[0.0, 1.0, 0.0],
              fov=39.3077, fov_axis="smaller", near_clip=10.0, far_clip=2800.0)
BSDFS = {
    "white": [0.885809, 0.698859, 0.666422],
    "red": [0.570068, 0.0430135, 0.0443706],
    "green": [0.105421, 0.37798, 0.076425],
    "light": [0.936461, 0.740433, 0.705267],
}
EMITTER_RADIANCE = [18.387, 10.9873, 2.75357]
LUMINAIRE_OFFSET_Y = -0.5
SHAPES = [  # (mesh, bsdf id)
    ("cbox_floor", "white"),
    ("cbox_ceiling", "white"),
    ("cbox_back", "white"),
    ("cbox_greenwall", "green"),
    ("cbox_redwall", "red"),
    ("cbox_smallbox", "white"),  # the XML uses the purple `box` test value here
    ("cbox_largebox", "white"),  # ditto
]

LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 / linear sRGB luminance weights
# Seeds: each --seed value owns SEED_SLOTS consecutive RNG "slots" (one per pass x chunk).
SEED_SLOTS = 1024
SCALAR_BLOCK = 32  # Mitsuba's scalar image-block size (MI_BLOCK_SIZE)
DEFAULT_MAX_WAVEFRONT = 1 << 22  # samples per mi.render call in the LLVM variant (memory bound)


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------

def die(msg: str):
    """Usage / input errors exit with 2 (1 is reserved for a failed comparison)."""
    print(msg, file=sys.stderr)
    sys.exit(2)


def scenes_dir() -> Path:
    env = os.environ.get("LFR_SCENES")
    if env:
        return Path(env).resolve()
    return (REPO_ROOT.parent / "shared" / "scenes").resolve()


def mesh_path(name: str) -> str:
    p = scenes_dir() / "cornell-box-mitsuba" / "meshes" / f"{name}.obj"
    if not p.is_file():
        die(f"error: mesh not found: {p} (set LFR_SCENES to the shared/scenes folder)")
    return str(p)


def json_path_for(exr: Path) -> Path:
    return exr.with_suffix(".json") if exr.suffix.lower() == ".exr" else Path(str(exr) + ".json")


def _llvm_candidates() -> list[str]:
    """libLLVM shared libraries on this machine, newest version first."""
    pats = ["/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
            "/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/lib64/libLLVM*.so*",
            "/usr/local/lib/libLLVM*.so*", "/opt/homebrew/opt/llvm/lib/libLLVM.dylib"]
    found = sorted({os.path.realpath(p) for pat in pats for p in glob.glob(pat)})

    def version(p: str):
        m = re.search(r"libLLVM\D*?(\d+)(?:\.(\d+))?(?:\.(\d+))?", os.path.basename(p))
        return tuple(int(x or 0) for x in m.groups()) if m else (0,)
    return sorted(found, key=version, reverse=True)


def _probe_llvm(libpath: str | None) -> bool:
    """Try the LLVM variant in a subprocess: an unsupported libLLVM aborts the process
    (e.g. drjit 1.5 + LLVM 15 dies with 'LLVM ERROR: Cannot select ... fminimum')."""
    env = dict(os.environ)
    if libpath:
        env["DRJIT_LIBLLVM_PATH"] = libpath
    try:
        r = subprocess.run([sys.executable, __file__, "_probe", "--variant", "llvm_ad_rgb"],
                           env=env, capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        return False
    return r.returncode == 0 and "PROBE_OK" in r.stdout


def pick_variant(requested: str) -> tuple[str, str | None]:
    """Returns (variant, DRJIT_LIBLLVM_PATH or None). 'auto' tries llvm_ad_rgb (newest
    libLLVM first), then falls back to scalar_rgb."""
    if requested == "scalar_rgb":
        return "scalar_rgb", None
    cands: list[str | None] = []
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        cands.append(os.environ["DRJIT_LIBLLVM_PATH"])
    else:
        cands += _llvm_candidates()[:3]
        cands.append(None)  # drjit's own search
    for c in cands:
        if _probe_llvm(c):
            return "llvm_ad_rgb", c
        print(f"note: llvm_ad_rgb does not work with libLLVM={c or '(default search)'}",
              file=sys.stderr)
    if requested == "llvm_ad_rgb":
        die("error: llvm_ad_rgb requested but no working libLLVM found "
                 "(drjit 1.5 needs LLVM >= 16; e.g. apt-get install libllvm19)")
    print("note: falling back to scalar_rgb", file=sys.stderr)
    return "scalar_rgb", None


def import_mitsuba(variant: str, llvm: str | None):
    if llvm:
        os.environ["DRJIT_LIBLLVM_PATH"] = llvm
    import mitsuba as mi
    mi.set_variant(variant)
    return mi


def _transform(mi):
    T = mi.ScalarTransform4f
    # Mitsuba >= 3.5: chained instance methods; older: static constructors.
    try:
        look = T().look_at(origin=CAMERA["origin"], target=CAMERA["target"], up=CAMERA["up"])
        shift = T().translate([0.0, LUMINAIRE_OFFSET_Y, 0.0])
    except TypeError:
        look = T.look_at(origin=CAMERA["origin"], target=CAMERA["target"], up=CAMERA["up"])
        shift = T.translate([0.0, LUMINAIRE_OFFSET_Y, 0.0])
    return look, shift


def scene_dict(mi, width: int, height: int) -> dict:
    look, shift = _transform(mi)
    d: dict = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": -1},
        "sensor": {
            "type": "perspective",
            "fov_axis": CAMERA["fov_axis"],
            "fov": CAMERA["fov"],
            "near_clip": CAMERA["near_clip"],
            "far_clip": CAMERA["far_clip"],
            "to_world": look,
            "sampler": {"type": "independent", "sample_count": 1},
            "film": {"type": "hdrfilm", "width": width, "height": height,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb",
                     "component_format": "float32"},
        },
    }
    for name, rgb in BSDFS.items():
        d[name] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": rgb}}
    d["luminaire"] = {
        "type": "obj", "filename": mesh_path("cbox_luminaire"), "to_world": shift,
        "bsdf": {"type": "ref", "id": "light"},
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": EMITTER_RADIANCE}},
    }
    for mesh, bsdf in SHAPES:
        d[mesh] = {"type": "obj", "filename": mesh_path(mesh), "bsdf": {"type": "ref", "id": bsdf}}
    return d


def orientation_check(img: np.ndarray) -> dict:
    """Red wall must be on the left, green on the right, light at the top."""
    w = img.shape[1]
    k = max(1, w // 10)
    left, right = img[:, :k].mean(axis=(0, 1)), img[:, -k:].mean(axis=(0, 1))
    eps = 1e-9
    red_left = float(left[0] / (left[1] + eps)) > float(right[0] / (right[1] + eps))
    green_right = float(right[1] / (right[0] + eps)) > float(left[1] / (left[0] + eps))
    lum_rows = (img @ LUMA).max(axis=1)
    h = img.shape[0]
    light_top = int(np.argmax(lum_rows)) < h // 2
    return {"red_wall_left": bool(red_left), "green_wall_right": bool(green_right),
            "light_in_top_half": bool(light_top),
            "ok": bool(red_left and green_right and light_top)}


# --------------------------------------------------------------------------------------------
# EXR I/O
# --------------------------------------------------------------------------------------------

def write_exr(path: Path, channels: dict[str, np.ndarray], attrs: dict) -> str:
    """Writes a single-part float32 EXR. Returns the backend used."""
    try:
        import OpenEXR
        hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        hdr.update(attrs)
        OpenEXR.File(hdr, {k: np.ascontiguousarray(v, dtype=np.float32)
                           for k, v in channels.items()}).write(str(path))
        return "OpenEXR"
    except ImportError:
        pass
    import mitsuba as mi  # fallback (variant already set by the caller)
    names = list(channels)
    arr = np.stack([channels[n] for n in names], axis=-1).astype(np.float32)
    bmp = mi.Bitmap(arr, mi.Bitmap.PixelFormat.MultiChannel, names)
    for k, v in attrs.items():
        bmp.metadata()[k] = v if isinstance(v, (int, float)) else str(v)
    bmp.write(str(path))
    return "mitsuba.Bitmap"


def read_exr(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """Reads every part of an EXR. Channel names are made 'part.channel' when the part has a
    name (the Rust `exr` crate writes each layer as a named part with plain channel names)
    unless the channel name already carries that prefix. Returns (channels, header attrs)."""
    try:
        import OpenEXR
    except ImportError:
        return _read_exr_mitsuba(path)
    f = OpenEXR.File(str(path), separate_channels=True)
    chans: dict[str, np.ndarray] = {}
    attrs: dict = {}
    for part in f.parts:
        pname = part.name() or ""
        for k, v in part.header.items():
            if isinstance(v, (int, float, str)):
                attrs.setdefault(k, v)
        for cname, ch in part.channels.items():
            full = cname if (not pname or cname.startswith(pname + ".")) else f"{pname}.{cname}"
            chans[full] = np.asarray(ch.pixels, dtype=np.float64)
    return chans, attrs


def _read_exr_mitsuba(path: Path):
    import mitsuba as mi
    if not mi.variant():
        mi.set_variant("scalar_rgb")
    bmp = mi.Bitmap(str(path))  # NB: reads only the first part of a multi-part file
    names = [bmp.struct_()[i].name for i in range(bmp.channel_count())]
    arr = np.array(bmp, dtype=np.float64).reshape(bmp.height(), bmp.width(), -1)
    return {n: arr[..., i] for i, n in enumerate(names)}, {}


def find_rgb_groups(names) -> dict[str, dict[str, str]]:
    """prefix -> {'R': fullname, 'G': ..., 'B': ...} for every complete RGB triple."""
    groups: dict[str, dict[str, str]] = {}
    for n in names:
        prefix, _, comp = n.rpartition(".")
        if comp.upper() in ("R", "G", "B"):
            groups.setdefault(prefix, {})[comp.upper()] = n
    return {p: g for p, g in groups.items() if len(g) == 3}


BEAUTY_NAMES = ("", "beauty", "rgb", "rgba", "color", "colour", "combined", "main", "image",
                "default", "mean")


def pick_layers(chans: dict, beauty: str | None, variance: str | None, what: str):
    groups = find_rgb_groups(chans)

    def choose(explicit, pred, prefer, kind):
        if explicit is not None:
            if explicit not in groups:
                die(f"error: {what}: no RGB layer '{explicit}' (have: {sorted(groups)})")
            return explicit
        cands = [p for p in groups if pred(p)]
        for pref in prefer:
            for p in cands:
                if p.lower() == pref or p.lower().endswith("." + pref) and pref:
                    return p
        if len(cands) == 1:
            return cands[0]
        die(f"error: {what}: cannot tell which layer is the {kind} among "
                 f"{sorted(groups) or sorted(chans)}; pass --{what}-{kind}-layer")

    def is_var(p):
        return "var" in p.lower()
    b = choose(beauty, lambda p: not is_var(p), BEAUTY_NAMES, "beauty")
    v = choose(variance, is_var, ("variance", "var"), "variance")
    img = np.stack([chans[groups[b][c]] for c in "RGB"], axis=-1)
    var = np.stack([chans[groups[v][c]] for c in "RGB"], axis=-1)
    return img, var, (b, v)


# --------------------------------------------------------------------------------------------
# render
# --------------------------------------------------------------------------------------------

def cmd_probe(args) -> int:
    mi = import_mitsuba(args.variant, None)
    scene = mi.load_dict(scene_dict(mi, 8, 8))
    img = np.array(mi.render(scene, spp=2, seed=0))
    assert np.isfinite(img).all() and img.mean() > 0
    print("PROBE_OK", mi.__version__, args.variant)
    return 0


def split_spp(spp: int, n: int) -> list[int]:
    return [spp // n + (1 if i < spp % n else 0) for i in range(n)]


def cmd_render(args) -> int:
    W, H, N, P, S = args.width, args.height, args.spp, args.passes, args.seed
    if P < 2:
        die("error: --passes must be >= 2 to estimate a variance")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    variant, llvm = pick_variant(args.variant)
    t_probe = time.perf_counter() - t_start
    mi = import_mitsuba(variant, llvm)
    import drjit as dr

    t0 = time.perf_counter()
    scene = mi.load_dict(scene_dict(mi, W, H))
    t_load = time.perf_counter() - t0

    # Chunking: the LLVM variant keeps a whole wavefront (W*H*spp lanes) in memory.
    if variant.startswith("llvm"):
        chunk_spp = max(1, min(N, args.max_wavefront // (W * H)))
    else:
        chunk_spp = N
    n_chunks = math.ceil(N / chunk_spp)
    chunks = split_spp(N, n_chunks)
    if P * n_chunks > SEED_SLOTS:
        die(f"error: passes x chunks = {P * n_chunks} > {SEED_SLOTS}; raise --max-wavefront")

    # RNG seeding. Mitsuba's scalar renderer seeds pixel i of block b with
    # seed*W*H + b*32*32 + i (uint32), so seeds must be spaced by the padded block area / (W*H)
    # to keep every (pass, chunk, pixel) stream distinct. The LLVM variant hashes
    # (seed, lane) with TEA, where any distinct seeds are independent; the same spacing is used.
    bs = SCALAR_BLOCK
    padded = math.ceil(W / bs) * bs * math.ceil(H / bs) * bs
    spacing = math.ceil(padded / (W * H))
    first_slot, last_slot = S * SEED_SLOTS, S * SEED_SLOTS + P * n_chunks - 1
    if variant == "scalar_rgb" and (last_slot * spacing + spacing) * W * H > 2**32:
        max_seed = (2**32 // (W * H * spacing) - P * n_chunks) // SEED_SLOTS
        die(f"error: --seed {S} too large for {W}x{H} in scalar_rgb (uint32 pixel seeds "
                 f"would wrap); use 0..{max(0, max_seed)}")

    print(f"Mitsuba {mi.__version__} ({variant}{', libLLVM=' + llvm if llvm else ''}), "
          f"{W}x{H}, {P} passes x {N} spp ({n_chunks} chunk(s) of <= {chunk_spp} spp), "
          f"seed {S}", flush=True)

    sum1 = np.zeros((H, W, 3))
    sum2 = np.zeros((H, W, 3))
    pass_times = []
    pass_means = []
    for p in range(P):
        tp = time.perf_counter()
        acc = np.zeros((H, W, 3))
        for c, n in enumerate(chunks):
            slot = first_slot + p * n_chunks + c
            img = mi.render(scene, spp=n, seed=slot * spacing)
            acc += np.array(img, dtype=np.float64)[..., :3] * n
        acc /= N
        dt = time.perf_counter() - tp
        pass_times.append(dt)
        pass_means.append(acc.mean(axis=(0, 1)).tolist())
        sum1 += acc
        sum2 += acc * acc
        print(f"  pass {p + 1}/{P}: {dt:.2f} s, mean RGB = "
              f"{np.array2string(acc.mean(axis=(0, 1)), precision=5)}", flush=True)
    mean = sum1 / P
    # Sample variance across passes / P  =  variance of the mean of the P passes.
    sample_var = np.maximum(sum2 - P * mean * mean, 0.0) / (P - 1)
    var_mean = sample_var / P

    orient = orientation_check(mean)
    if not orient["ok"]:
        print(f"WARNING: unexpected orientation: {orient}", file=sys.stderr)

    attrs = {"lfrPasses": int(P), "lfrSppPerPass": int(N), "lfrSeed": int(S),
             "lfrRenderer": f"Mitsuba {mi.__version__} {variant}",
             "lfrScene": "cornell-box-mitsuba (white boxes, path max_depth=-1, box filter)"}
    chans = {"R": mean[..., 0], "G": mean[..., 1], "B": mean[..., 2],
             "variance.R": var_mean[..., 0], "variance.G": var_mean[..., 1],
             "variance.B": var_mean[..., 2]}
    backend = write_exr(out, chans, attrs)

    # Verify by reading back.
    back, back_attrs = read_exr(out)
    rb_img, rb_var, _ = pick_layers(back, None, None, "reference")
    assert np.allclose(rb_img, mean.astype(np.float32), rtol=0, atol=0), "EXR read-back mismatch"
    assert np.allclose(rb_var, var_mean.astype(np.float32), rtol=0, atol=0), "EXR read-back mismatch"

    total = time.perf_counter() - t_start
    render_time = float(sum(pass_times))
    rel_se = np.sqrt(var_mean.sum(axis=(0, 1))) / (W * H) / np.maximum(mean.mean(axis=(0, 1)), 1e-30)
    info = {
        "exr": str(out.resolve()),
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "mitsuba_version": mi.__version__,
        "drjit_version": dr.__version__,
        "variant": variant,
        "drjit_libllvm_path": llvm,
        "width": W, "height": H, "spp_per_pass": N, "passes": P, "total_spp": N * P,
        "seed": S, "chunks_per_pass": n_chunks, "rng_seed_values":
            [(first_slot + i) * spacing for i in range(P * n_chunks)],
        "variance_dof": P - 1,
        "scene": {
            "meshes_dir": str(scenes_dir() / "cornell-box-mitsuba" / "meshes"),
            "camera": CAMERA, "bsdfs": BSDFS, "shapes": SHAPES,
            "luminaire": {"mesh": "cbox_luminaire", "bsdf": "light",
                          "translate_y": LUMINAIRE_OFFSET_Y,
                          "area_emitter_radiance": EMITTER_RADIANCE, "one_sided": True},
            "integrator": {"type": "path", "max_depth": -1, "rr_depth": 5},
            "film": {"rfilter": "box", "pixel_format": "rgb"},
            "sampler": "independent",
        },
        "timing_s": {"variant_probe": round(t_probe, 3), "scene_load": round(t_load, 3),
                     "render": round(render_time, 3), "per_pass": [round(t, 3) for t in pass_times],
                     "total": round(total, 3)},
        "samples_per_second": W * H * N * P / render_time if render_time > 0 else None,
        "image_mean_rgb": mean.mean(axis=(0, 1)).tolist(),
        "image_mean_rel_stderr_rgb": rel_se.tolist(),
        "pass_means_rgb": pass_means,
        "orientation_check": orient,
        "exr_writer": backend,
        "exr_channels": list(chans),
        "host": {"cpus": os.cpu_count(), "machine": platform.machine(),
                 "python": platform.python_version()},
    }
    jp = json_path_for(out)
    jp.write_text(json.dumps(info, indent=2) + "\n")
    print(f"wrote {out} and {jp}: render {render_time:.1f} s "
          f"({info['samples_per_second'] / 1e6:.2f} M samples/s), total {total:.1f} s; "
          f"orientation ok: {orient['ok']}")
    return 0


# --------------------------------------------------------------------------------------------
# compare
# --------------------------------------------------------------------------------------------

def _norm_sf(x: float) -> float:
    return 0.5 * math.erfc(x / math.sqrt(2.0))


_GL_X, _GL_W = np.polynomial.legendre.leggauss(96)


def _t_two_sided(x: float, nu: np.ndarray) -> np.ndarray:
    """P(|T| > x) for Student-t with nu (array, may be inf) degrees of freedom."""
    nu = np.asarray(nu, dtype=np.float64)
    out = np.full(nu.shape, 2.0 * _norm_sf(x))
    fin = np.isfinite(nu) & (nu < 1e6)
    if fin.any():
        # Bin the dof so the integral is done on a few hundred distinct values only.
        q = np.round(np.log(np.clip(nu[fin], 0.5, 1e6)) * 200.0) / 200.0
        uq, inv = np.unique(q, return_inverse=True)
        n = np.exp(uq)[:, None]
        # integral_x^inf f(t) dt with t = x/u, u in (0, 1]
        u = 0.5 * (_GL_X + 1.0)[None, :]
        t = x / u
        lg = np.vectorize(math.lgamma)
        logc = lg((n + 1) / 2) - lg(n / 2) - 0.5 * np.log(n * math.pi)
        f = np.exp(logc - (n + 1) / 2 * np.log1p(t * t / n)) * x / (u * u)
        tail = (f * 0.5 * _GL_W[None, :]).sum(axis=1)
        out[fin] = (2.0 * tail)[inv]
    return out


def cmd_compare(args) -> int:
    ours_ch, ours_attrs = read_exr(Path(args.ours))
    ref_ch, ref_attrs = read_exr(Path(args.reference))
    a, va, la = pick_layers(ours_ch, args.ours_beauty_layer, args.ours_variance_layer, "ours")
    b, vb, lb = pick_layers(ref_ch, None, None, "reference")
    if a.shape != b.shape:
        print(f"error: size mismatch: ours {a.shape[1]}x{a.shape[0]}, "
              f"reference {b.shape[1]}x{b.shape[0]}", file=sys.stderr)
        return 2
    H, W, _ = a.shape
    npix = H * W
    tiny = args.tiny
    z = (a - b) / np.sqrt(np.maximum(va, 0) + np.maximum(vb, 0) + tiny)
    nonfinite = ~(np.isfinite(a) & np.isfinite(b) & np.isfinite(va) & np.isfinite(vb))
    absz = np.where(nonfinite, np.inf, np.abs(z))
    thr = args.threshold
    ch_pass = absz < thr
    pix_pass = ch_pass.all(axis=-1)

    # Expected false-rejection rates if both renderers are unbiased.
    p_gauss = 2.0 * _norm_sf(thr)
    nu_ref = args.ref_dof if args.ref_dof is not None else (
        float(ref_attrs["lfrPasses"]) - 1 if "lfrPasses" in ref_attrs else math.inf)
    nu_ours = args.ours_dof if args.ours_dof is not None else (
        float(ours_attrs["lfrPasses"]) - 1 if "lfrPasses" in ours_attrs else math.inf)
    # Welch-Satterthwaite effective dof per pixel and channel.
    va_, vb_ = np.maximum(va, 0), np.maximum(vb, 0)
    den = (va_ ** 2 / nu_ours if math.isfinite(nu_ours) else 0.0) + \
          (vb_ ** 2 / nu_ref if math.isfinite(nu_ref) else 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        nu_eff = np.where(den > 0, (va_ + vb_) ** 2 / np.where(den > 0, den, 1.0), np.inf)
    p_t = _t_two_sided(thr, nu_eff)
    p_t_pix = 1.0 - np.prod(1.0 - p_t, axis=-1)

    ma, mb = a.mean(axis=(0, 1)), b.mean(axis=(0, 1))
    ya, yb = float(ma @ LUMA), float(mb @ LUMA)
    # Standard error of the image-mean difference (pixels are independent).
    se = np.sqrt((va_ + vb_).sum(axis=(0, 1))) / npix
    # The EXRs carry no R/G/B covariances; the channels of one path are almost perfectly
    # correlated (measured: summing L_i^2 var_i underestimates the luminance sd by ~1.45x), so
    # use the perfect-correlation value sd_Y = sum_i L_i sd_i per pixel.
    se_y = math.sqrt(float(((np.sqrt(va_) @ LUMA) ** 2 + (np.sqrt(vb_) @ LUMA) ** 2).sum())) / npix
    rel_px = np.abs(a - b) / (b + 0.01)
    lum_a, lum_b = a @ LUMA, b @ LUMA
    rel_px_y = np.abs(lum_a - lum_b) / (lum_b + 0.01)
    zf = np.where(np.isfinite(z), z, np.nan)

    worst = np.argsort(absz.max(axis=-1), axis=None)[::-1][: args.worst]
    worst_list = []
    for idx in worst:
        y, x = divmod(int(idx), W)
        worst_list.append({"x": x, "y": y, "z_rgb": [float(v) for v in z[y, x]],
                           "ours": [float(v) for v in a[y, x]], "ref": [float(v) for v in b[y, x]],
                           "sd_ours": [float(v) for v in np.sqrt(va_[y, x])],
                           "sd_ref": [float(v) for v in np.sqrt(vb_[y, x])]})

    # Tile test: sums over t x t pixel tiles are close to Gaussian and their variances have
    # many dof, so this is robust to the skew / low-dof effects that hit single pixels.
    tile = None
    t = args.tile
    if t and H // t and W // t:
        def tsum(x):
            return x[: H // t * t, : W // t * t].reshape(H // t, t, W // t, t, 3).sum(axis=(1, 3))
        zt = (tsum(a) - tsum(b)) / np.sqrt(tsum(va_) + tsum(vb_) + tiny)
        zt = np.where(np.isfinite(zt), zt, np.inf)
        tile = {"size": t, "count": int(zt.shape[0] * zt.shape[1]),
                "pass_all_channels": float((np.abs(zt) < thr).all(axis=-1).mean()),
                "z_mean_rgb": zt.mean(axis=(0, 1)).tolist(),
                "z_std_rgb": zt.std(axis=(0, 1)).tolist(),
                "abs_z_max": float(np.abs(zt).max())}

    frac_pix = float(pix_pass.mean())
    mean_rel_y = abs(ya - yb) / yb if yb > 0 else math.inf
    ok = frac_pix >= args.min_pass and mean_rel_y < args.max_mean_rel
    res = {
        "ours": str(args.ours), "reference": str(args.reference),
        "layers": {"ours": {"beauty": la[0], "variance": la[1]},
                   "reference": {"beauty": lb[0], "variance": lb[1]}},
        "width": W, "height": H, "threshold_abs_z": thr, "tiny": tiny,
        "pixels_pass_all_channels": frac_pix,
        "pixel_channels_pass": float(ch_pass.mean()),
        "pixel_channels_pass_rgb": ch_pass.mean(axis=(0, 1)).tolist(),
        "expected_false_rejection": {
            "per_channel_gaussian": p_gauss,
            "per_pixel_gaussian_3_independent_channels": 1.0 - (1.0 - p_gauss) ** 3,
            "dof_ours": nu_ours, "dof_reference": nu_ref,
            "per_channel_student_t": float(p_t.mean()),
            "per_pixel_student_t": float(p_t_pix.mean()),
            "note": "Student-t uses Welch-Satterthwaite dof from the variance estimates' dof "
                    "(reference: passes-1); channels are correlated, so the per-pixel rate is "
                    "an upper estimate; heavy-tailed path-tracing noise raises it.",
        },
        "nonfinite_pixels": int(nonfinite.any(axis=-1).sum()),
        "z_mean_rgb": np.nanmean(zf, axis=(0, 1)).tolist(),
        "z_std_rgb": np.nanstd(zf, axis=(0, 1)).tolist(),
        "z_mean_stderr": 1.0 / math.sqrt(npix),
        "abs_z_quantiles": {q: float(np.nanquantile(np.abs(zf), float(q)))
                            for q in ("0.5", "0.9", "0.99", "0.999", "1.0")},
        "frac_abs_z_gt_5": float((absz > 5).mean()),
        "image_mean_ours_rgb": ma.tolist(), "image_mean_ref_rgb": mb.tolist(),
        "image_mean_rel_diff_rgb": (np.abs(ma - mb) / np.where(mb > 0, mb, np.nan)).tolist(),
        "image_mean_rel_diff_luminance": mean_rel_y,
        "image_mean_diff_z_rgb": ((ma - mb) / np.maximum(se, 1e-300)).tolist(),
        "image_mean_diff_z_luminance": (ya - yb) / max(se_y, 1e-300),
        "image_mean_rel_stderr_luminance": se_y / yb if yb > 0 else None,
        "mean_abs_rel_diff_pixels_rgb": rel_px.mean(axis=(0, 1)).tolist(),
        "mean_abs_rel_diff_pixels_all": float(rel_px.mean()),
        "mean_abs_rel_diff_pixels_luminance": float(rel_px_y.mean()),
        "tiles": tile,
        "worst_pixels": worst_list,
        "criteria": {"min_pixels_pass": args.min_pass, "max_image_mean_rel_diff_luminance":
                     args.max_mean_rel},
        "pass": bool(ok),
    }

    f3 = lambda v: ", ".join(f"{x:.4g}" for x in v)  # noqa: E731
    print(f"compare {args.ours}  vs  reference {args.reference}  ({W}x{H})")
    print(f"  layers: ours beauty='{la[0]}' variance='{la[1]}'; "
          f"reference beauty='{lb[0]}' variance='{lb[1]}'")
    print(f"  pixels with all 3 channels |z| < {thr:g}: {100 * frac_pix:.3f} %   "
          f"(need >= {100 * args.min_pass:g} %)")
    print(f"  pixel-channels with |z| < {thr:g}:       {100 * ch_pass.mean():.3f} %   "
          f"(R,G,B: {f3(100 * ch_pass.mean(axis=(0, 1)))} %)")
    print(f"  expected false rejection if unbiased: per channel {100 * p_gauss:.3f} % (Gaussian), "
          f"{100 * p_t.mean():.3f} % (Student-t, dof ours={nu_ours:g}, ref={nu_ref:g}); per pixel "
          f"{100 * (1 - (1 - p_gauss) ** 3):.3f} % / {100 * p_t_pix.mean():.3f} %")
    print(f"  z mean (R,G,B): {f3(res['z_mean_rgb'])}  (+-{res['z_mean_stderr']:.3g}); "
          f"z std: {f3(res['z_std_rgb'])}; |z| 99.9%: {res['abs_z_quantiles']['0.999']:.3g}, "
          f"max {res['abs_z_quantiles']['1.0']:.3g}; non-finite pixels {res['nonfinite_pixels']}")
    print(f"  image mean ours (R,G,B) {f3(ma)}  ref {f3(mb)}")
    print(f"  |mean(ours)-mean(ref)|/mean(ref): R,G,B {f3(100 * np.array(res['image_mean_rel_diff_rgb']))} %,"
          f" luminance {100 * mean_rel_y:.4f} % (need < {100 * args.max_mean_rel:g} %; "
          f"1-sigma noise {100 * (res['image_mean_rel_stderr_luminance'] or 0):.3g} %, "
          f"z = {res['image_mean_diff_z_luminance']:.2f})")
    print(f"  mean over pixels |ours-ref|/(ref+0.01): R,G,B {f3(res['mean_abs_rel_diff_pixels_rgb'])},"
          f" all {res['mean_abs_rel_diff_pixels_all']:.4g}, luminance "
          f"{res['mean_abs_rel_diff_pixels_luminance']:.4g}")
    if tile:
        print(f"  {t}x{t} tiles ({tile['count']}) with all 3 channels |z| < {thr:g}: "
              f"{100 * tile['pass_all_channels']:.2f} %; tile z mean {f3(tile['z_mean_rgb'])}, "
              f"std {f3(tile['z_std_rgb'])}, max |z| {tile['abs_z_max']:.3g}  (informational)")
    if worst_list and args.worst:
        wp = worst_list[0]
        print(f"  worst pixel (x={wp['x']}, y={wp['y']}): z = {f3(wp['z_rgb'])}, "
              f"ours {f3(wp['ours'])}, ref {f3(wp['ref'])}")
    print(f"  RESULT: {'PASS' if ok else 'FAIL'}")

    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(res, indent=2, default=float) + "\n")
    if args.zmap:
        write_exr(Path(args.zmap), {"R": z[..., 0], "G": z[..., 1], "B": z[..., 2]},
                  {"lfrNote": "z = (ours - ref) / sqrt(var_ours + var_ref + tiny)"})
    return 0 if ok else 1


# --------------------------------------------------------------------------------------------

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)

    r = sub.add_parser("render", help="render the Mitsuba reference (mean + variance EXR)")
    r.add_argument("--width", type=int, default=256)
    r.add_argument("--height", type=int, default=256)
    r.add_argument("--spp", type=int, required=True, help="samples per pixel per pass")
    r.add_argument("--passes", type=int, default=16,
                   help="independent passes (>= 2); the variance estimate has passes-1 dof, so "
                        "prefer >= 16 for a reference (default 16)")
    r.add_argument("--seed", type=int, default=0, help="distinct seeds give independent renders")
    r.add_argument("--out", required=True, help="output EXR (a .json is written beside it)")
    r.add_argument("--variant", choices=("auto", "scalar_rgb", "llvm_ad_rgb"), default="auto")
    r.add_argument("--max-wavefront", type=int, default=DEFAULT_MAX_WAVEFRONT,
                   help="max samples per mi.render call in llvm_ad_rgb (memory bound)")

    c = sub.add_parser("compare", help="z-test our EXR against a reference EXR")
    c.add_argument("--ours", required=True)
    c.add_argument("--reference", required=True)
    c.add_argument("--json", help="write the summary as JSON here")
    c.add_argument("--zmap", help="write the per-pixel z-scores as an EXR here")
    c.add_argument("--threshold", type=float, default=3.0, help="|z| threshold (default 3)")
    c.add_argument("--tiny", type=float, default=1e-12, help="added to the variance sum")
    c.add_argument("--min-pass", type=float, default=0.99,
                   help="required fraction of pixels passing in all channels (default 0.99)")
    c.add_argument("--max-mean-rel", type=float, default=0.01,
                   help="max relative difference of the image-mean luminance (default 0.01)")
    c.add_argument("--ours-beauty-layer", help="layer prefix of our beauty (default: auto)")
    c.add_argument("--ours-variance-layer", help="layer prefix of our variance (default: auto)")
    c.add_argument("--ours-dof", type=float,
                   help="dof of our variance estimate (default: passes-1 from the header, else inf)")
    c.add_argument("--ref-dof", type=float,
                   help="dof of the reference variance (default: lfrPasses-1 from its header)")
    c.add_argument("--tile", type=int, default=8,
                   help="also z-test sums over TILE x TILE pixel tiles (informational; 0 = off)")
    c.add_argument("--worst", type=int, default=10, help="list this many worst pixels in the JSON")

    pr = sub.add_parser("_probe", help=argparse.SUPPRESS)
    pr.add_argument("--variant", required=True)

    args = ap.parse_args(argv)
    return {"render": cmd_render, "compare": cmd_compare, "_probe": cmd_probe}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
