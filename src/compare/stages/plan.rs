//! Stage 1, the plan: every check that needs no traced image, before anything is traced or
//! written. It reads the arguments (counts within `tracer::limits`, the tone map), resolves
//! the methods (the registry's, and `probes` on the tracer's side), loads the scene and sets it
//! up for the effect (`effect::prepare_scene`), refuses a method that would blur what the scene
//! holds, checks that the comparison fits in memory and that the reference cache is usable, and
//! asks each method whether its dependencies are there (a method without them is skipped).

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use recon::metrics::ToneMap;
use recon::registry::{self, Registered};
use recon::Effect;
use tracer::limits::{MAX_COMPARE_SIDE, MAX_COMPARE_SPP, MAX_RECON_RAYS, MAX_SPP};
use tracer::{Accel, Scene};

use super::super::effect::{default_ao_radius, default_for as default_effect, prepare_scene, Tracing};
use super::super::results::Skipped;
use super::super::{probes_method, reference, CompareArgs};

/// What a comparison will do: checked arguments, the scene as set up, the methods that run.
pub struct Plan<'a> {
    pub args: &'a CompareArgs,
    pub effect: Effect,
    /// `--out`.
    pub dir: &'a Path,
    /// The inputs' and the ladder's seed (the reference's two are derived from it).
    pub seed: u32,
    /// The scene file's bytes (the embedded scene's text without one): the cache keys hash them.
    pub scene_text: Vec<u8>,
    /// The scene as set up for the effect.
    pub scene: Scene,
    /// The path length traced (1 for soft shadows).
    pub max_bounces: u32,
    pub width: u32,
    pub height: u32,
    /// Ambient-occlusion radius in scene units (used by `ao` only).
    pub ao_radius: f32,
    /// `--exposure`'s tone map, if given (else the reference's, in the reference stage).
    pub tone_given: Option<ToneMap>,
    /// The reference cache.
    pub cache: PathBuf,
    /// The registry's methods whose dependencies are there, in the order named.
    pub methods: Vec<Registered>,
    /// The `probes` methods (`probes_method`), in the order named.
    pub probe_methods: Vec<probes_method::ProbesMethod>,
    /// The methods left out because a dependency is missing.
    pub skipped: Vec<Skipped>,
    /// The path-tracing ladder's sample counts ([`ladder`]).
    pub ladder: Vec<u32>,
    /// Progress bars and lines (not `--quiet`).
    pub progress: bool,
}

impl<'a> Plan<'a> {
    /// Checks `args` and sets the comparison up (module doc); `Ok` only when every check passed.
    pub fn new(args: &'a CompareArgs) -> Result<Plan<'a>> {
        let Some(dir) = args.out.as_deref() else {
            bail!("--out is required (or --list-methods)");
        };
        let seed = args.trace.run.seed_or(1);
        check_counts(args)?;
        let tone_given = match args.exposure {
            Some(exposure) => Some(ToneMap::with_exposure(exposure).map_err(|e| anyhow::anyhow!("--exposure: {e}"))?),
            None => None,
        };
        // With --effect given, the methods are checked before the scene is read.
        let resolve = |effect: Effect| -> Result<_> {
            let (names, probe_methods) = split_probes(&args.methods, effect, seed, args.recon_rays.as_deref())?;
            Ok((resolve_methods(&names, effect)?, probe_methods))
        };
        let early = args.effect.map(resolve).transpose()?;

        // What the comparison removes and writes in OUT against every file it reads, before the
        // scene is read and again with the files it references.
        let cache = reference::cache_dir(args.cache_dir.as_deref());
        let references = args.reference.as_deref().unwrap_or_default();
        let mut outputs = crate::outputs::comparison_plan(dir, args.trace.scene.as_deref(), references, &cache);
        outputs.check()?;
        let mut scene = args.trace.load_scene()?;
        outputs.scene(&scene).check()?;
        let scene_text = crate::fingerprint::scene_text(args.trace.scene.as_deref())?;
        if let Some(radius) = args.aperture_radius {
            if !(radius.is_finite() && radius >= 0.0) {
                bail!("--aperture-radius must be finite and at least 0, got {radius}");
            }
            scene.camera.aperture_radius = radius;
        }
        if let Some(distance) = args.focus_distance {
            if !(distance.is_finite() && distance > 0.0) {
                bail!("--focus-distance must be positive and finite, got {distance}");
            }
            scene.camera.focus_distance = distance;
        }
        let effect = args.effect.unwrap_or_else(|| {
            let (effect, why) = default_effect(&scene);
            eprintln!("compare: no --effect given: {} for {} ({why})", effect.name(), scene.source.display());
            effect
        });
        let (methods, probe_methods) = match early {
            Some(resolved) => resolved,
            None => resolve(effect)?,
        };
        let max_bounces = prepare_scene(effect, &mut scene, args.trace.size.max_bounces)?;
        let glossy_scene = tracer::samples::secondary::scene_is_glossy(&scene);
        let (methods, mut skipped) = skip_blurring_on_glossy_scene(methods, effect, glossy_scene);
        let (width, height) =
            (args.trace.size.width.unwrap_or(scene.width), args.trace.size.height.unwrap_or(scene.height));
        if width == 0 || height == 0 || width > MAX_COMPARE_SIDE || height > MAX_COMPARE_SIDE {
            bail!("--width and --height must be in 1..={MAX_COMPARE_SIDE}, got {width}x{height}");
        }
        let threads = args.trace.run.thread_count()?;
        let ao_radius = match args.ao_radius {
            Some(r) if !(r.is_finite() && r > 0.0) => bail!("--ao-radius must be positive and finite, got {r}"),
            Some(r) => r,
            None => default_ao_radius(&scene),
        };
        check_memory(args, &methods, &probe_methods, (width, height), threads)?;
        reference::check_cache_dir(&cache)?;
        let (methods, unavailable) = available(methods);
        skipped.extend(unavailable);
        Ok(Plan {
            args,
            effect,
            dir,
            seed,
            scene_text,
            scene,
            max_bounces,
            width,
            height,
            ao_radius,
            tone_given,
            cache,
            methods,
            probe_methods,
            skipped,
            ladder: ladder(args.pt_max_spp, &args.spp),
            progress: !args.trace.quiet,
        })
    }

    /// How the effect's images are traced with `accel` (built on [`Plan::scene`]).
    pub fn tracing<'s>(&'s self, accel: &'s Accel) -> Tracing<'s> {
        Tracing {
            scene: &self.scene,
            accel,
            effect: self.effect,
            width: self.width,
            height: self.height,
            max_bounces: self.max_bounces,
            ao_radius: self.ao_radius,
            threads: self.args.trace.run.threads,
        }
    }

    /// The input sample counts (`--spp`).
    pub fn input_spp(&self) -> &[u32] {
        &self.args.spp
    }

    /// The sample counts `method` runs at: a method that reads the path-traced frame (the
    /// denoiser, `Input::Image`) runs on every rung of the ladder, whose frames are traced
    /// anyway, so that the peer's curve spans path tracing's time range and a reconstruction's
    /// quality is read on it rather than beyond it; every other method at `--spp`.
    pub fn spp_of(&self, method: &Registered) -> &[u32] {
        if method.input() == recon::method::Input::Image {
            &self.ladder
        } else {
            &self.args.spp
        }
    }

    /// The reconstruction rays `method` sweeps: `--recon-rays`, else its own default (`[0]`
    /// for a method without such a parameter, whatever `--recon-rays` says).
    pub fn rays_of(&self, method: &Registered) -> Vec<u32> {
        let default_rays = method.default_recon_rays(self.effect);
        if default_rays == [0] {
            vec![0]
        } else {
            self.args.recon_rays.clone().unwrap_or(default_rays)
        }
    }

    /// Worker threads; 0 = all cores.
    pub fn threads(&self) -> usize {
        self.args.trace.run.threads
    }
}

/// The counts of the arguments within their limits.
fn check_counts(args: &CompareArgs) -> Result<()> {
    if args.spp.is_empty() || args.spp.iter().any(|&s| s == 0 || s > MAX_COMPARE_SPP) {
        bail!("--spp: every input sample count must be in 1..={MAX_COMPARE_SPP}, got {:?}", args.spp);
    }
    if args.reference_spp < 2 || args.reference_spp > MAX_SPP || args.reference_spp % 2 != 0 {
        bail!("--reference-spp must be even (two halves) and in 2..={MAX_SPP}, got {}", args.reference_spp);
    }
    if args.pt_max_spp == 0 || args.pt_max_spp > MAX_COMPARE_SPP {
        bail!("--pt-max-spp must be in 1..={MAX_COMPARE_SPP}, got {}", args.pt_max_spp);
    }
    if let Some(rays) = &args.recon_rays {
        if rays.is_empty() || rays.iter().any(|&r| r == 0 || r > MAX_RECON_RAYS) {
            bail!("--recon-rays: every count must be in 1..={MAX_RECON_RAYS}, got {rays:?}");
        }
    }
    Ok(())
}

/// `--methods` split into the registry's names and the `probes` methods, which sit on the
/// tracer (the harness's hook, `probes_method`), without repeats. A probes method traces no
/// input, so `--spp` does not apply to it; `--recon-rays` sets its primary rays per pixel
/// (`pixel_samples`), one run per count, unless its spec sets `pixel_samples` itself.
fn split_probes(
    methods: &[String],
    effect: Effect,
    seed: u32,
    recon_rays: Option<&[u32]>,
) -> Result<(Vec<String>, Vec<probes_method::ProbesMethod>)> {
    let mut probe_methods: Vec<probes_method::ProbesMethod> = Vec::new();
    let mut names: Vec<String> = Vec::new();
    for name in methods {
        let Some(method) = probes_method::ProbesMethod::parse(name, seed)? else {
            names.push(name.clone());
            continue;
        };
        if effect != Effect::Indirect {
            bail!("--methods: probes handles --effect indirect only, not {}", effect.name());
        }
        let sets_rays = method.name.split(':').any(|option| option.starts_with("pixel_samples="));
        let runs = match recon_rays {
            Some(rays) if !sets_rays => {
                let mut runs = Vec::new();
                for rays in rays {
                    let spec = format!("{}:pixel_samples={rays}", method.name);
                    runs.push(probes_method::ProbesMethod::parse(&spec, seed)?.expect("a probes spec stays one"));
                }
                let specs: Vec<&str> = runs.iter().map(|m| m.name.as_str()).collect();
                eprintln!(
                    "compare: {}: --recon-rays sets its primary rays per pixel: {}",
                    method.name,
                    specs.join(", ")
                );
                runs
            }
            _ => vec![method],
        };
        for method in runs {
            if !probe_methods.iter().any(|m| m.name == method.name) {
                probe_methods.push(method);
            }
        }
    }
    Ok((names, probe_methods))
}

/// The methods named on the command line, in order, without repeats.
pub fn resolve_methods(names: &[String], effect: Effect) -> Result<Vec<Registered>> {
    let mut methods: Vec<Registered> = Vec::new();
    for name in names.iter().map(|n| n.trim()).filter(|n| !n.is_empty()) {
        if methods.iter().any(|m| m.name() == name) {
            continue;
        }
        let Some(method) = registry::find(name).map_err(|e| anyhow::anyhow!("--methods: {e}"))? else {
            let known: Vec<_> = registry::METHODS.iter().map(|m| m.name).collect();
            bail!("--methods: unknown method `{name}`; known: {}", known.join(", "));
        };
        if !method.supports(effect) {
            bail!("--methods: {name} does not handle --effect {}", effect.name());
        }
        methods.push(method);
    }
    Ok(methods)
}

/// Skips, with a notice and before anything is traced, every method that blurs glossy
/// reflections (`Method::blurs_glossy_reflections`: the screen-space filters, `ilfr:grain=filter`)
/// in an indirect or glossy comparison of a scene with glossy materials: that scene's indirect
/// light holds glossy reflections (its sample files carry `weight`). The other methods run.
fn skip_blurring_on_glossy_scene(
    methods: Vec<Registered>,
    effect: Effect,
    glossy_scene: bool,
) -> (Vec<Registered>, Vec<Skipped>) {
    if !matches!(effect, Effect::Indirect | Effect::Glossy) || !glossy_scene {
        return (methods, Vec::new());
    }
    let mut skipped = Vec::new();
    let kept = methods
        .into_iter()
        .filter(|method| {
            if !method.blurs_glossy_reflections() {
                return true;
            }
            let reason = format!(
                "it blurs glossy reflections, and this scene has glossy materials (it applies to diffuse scenes{})",
                if method.name() != method.spec.name {
                    format!("; {} keeps them", method.spec.name)
                } else {
                    String::new()
                }
            );
            eprintln!("skipping {}: {reason}", method.name());
            skipped.push(Skipped { method: method.name().to_string(), reason });
            false
        })
        .collect();
    (kept, skipped)
}

/// Refuses a comparison whose images would not fit in memory, before anything is traced: one
/// render at a time (`tracer::memory::RENDER_BYTES_PER_PIXEL`), the reference and its halves,
/// every run's image and its FLIP copy, and the frames and guide buffers kept per input spp;
/// with `probes` methods, the largest of their precomputes, compressions and images
/// (`probes::memory`: they run one at a time, beside the images kept).
fn check_memory(
    args: &CompareArgs,
    methods: &[Registered],
    probe_methods: &[probes_method::ProbesMethod],
    (width, height): (u32, u32),
    threads: usize,
) -> Result<()> {
    let ladder_runs = ladder(args.pt_max_spp, &args.spp).len() as u64;
    let rays = args.recon_rays.as_ref().map_or(3, Vec::len) as u64;
    let method_runs = (methods.len() + probe_methods.len()) as u64 * args.spp.len() as u64 * rays;
    // A method reading the traced frame runs on every rung, and every rung's frame (colour,
    // albedo, normal: 36 bytes a pixel) is kept for it.
    let frame_readers = methods.iter().filter(|m| m.input() == recon::method::Input::Image).count() as u64;
    let method_runs = method_runs + frame_readers * ladder_runs;
    let kept_frames = if frame_readers > 0 { 36 * ladder_runs } else { 0 };
    let inputs = args.spp.len() as u64;
    let per_pixel =
        tracer::memory::RENDER_BYTES_PER_PIXEL + 3 * 12 + 24 * (ladder_runs + method_runs) + 100 * inputs + kept_frames;
    let images = width as u64 * height as u64 * per_pixel;
    let what = format!("a comparison at {width}x{height} with {} runs", ladder_runs + method_runs);
    let largest_probes = probe_methods
        .iter()
        .map(|method| (method, probes_method::memory_estimate(method, (width, height), threads)))
        .max_by_key(|(_, estimate)| estimate.total());
    match largest_probes {
        None => tracer::memory::check(&what, images)?,
        Some((method, estimate)) => {
            let what = estimate.describe(&format!("{what}, its images and {}", method.name));
            tracer::memory::check(&what, images + estimate.total())?
        }
    }
    Ok(())
}

/// The methods whose dependencies are there, and the others as skipped (each said on standard
/// error).
fn available(methods: Vec<Registered>) -> (Vec<Registered>, Vec<Skipped>) {
    let mut skipped = Vec::new();
    let available = methods
        .into_iter()
        .filter(|method| match method.available() {
            Ok(()) => true,
            Err(reason) => {
                eprintln!("skipping {}: {reason}", method.name());
                skipped.push(Skipped { method: method.name().to_string(), reason: reason.to_string() });
                false
            }
        })
        .collect();
    (available, skipped)
}

/// The ladder's sample counts: powers of two up to `max`, plus every input spp, so that each
/// method's input spp has a path-traced image of the same samples beside it.
pub fn ladder(max: u32, input_spp: &[u32]) -> Vec<u32> {
    let mut spp: Vec<u32> = std::iter::successors(Some(1u32), |s| s.checked_mul(2)).take_while(|&s| s <= max).collect();
    spp.extend_from_slice(input_spp);
    spp.sort_unstable();
    spp.dedup();
    spp
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recon_rays_set_the_probes_rays_per_pixel_unless_the_spec_does() {
        let methods = |list: &[&str]| list.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let (names, probes) =
            split_probes(&methods(&["ilfr", "probes:order=3"]), Effect::Indirect, 1, Some(&[4, 16])).unwrap();
        assert_eq!(names, ["ilfr"]);
        let runs: Vec<(&str, u32, usize)> =
            probes.iter().map(|m| (m.name.as_str(), m.pixel_samples, m.precompute.transport.order)).collect();
        assert_eq!(runs, [("probes:order=3:pixel_samples=4", 4, 3), ("probes:order=3:pixel_samples=16", 16, 3)]);
        // Its own count wins; without --recon-rays the default stays.
        let (_, probes) = split_probes(&methods(&["probes:pixel_samples=2"]), Effect::Indirect, 1, Some(&[4])).unwrap();
        assert_eq!(probes.iter().map(|m| m.pixel_samples).collect::<Vec<_>>(), [2]);
        let (_, probes) = split_probes(&methods(&["probes"]), Effect::Indirect, 1, None).unwrap();
        assert_eq!(probes.iter().map(|m| m.pixel_samples).collect::<Vec<_>>(), [probes::defaults::PIXEL_SAMPLES]);
        // A count the image cannot take is refused, naming the option.
        let error = split_probes(&methods(&["probes"]), Effect::Indirect, 1, Some(&[4096])).unwrap_err().to_string();
        assert!(error.contains("pixel_samples"), "{error}");
    }

    #[test]
    fn ladder_is_powers_of_two_plus_inputs() {
        assert_eq!(ladder(16, &[3, 4]), vec![1, 2, 3, 4, 8, 16]);
        assert_eq!(ladder(1, &[]), vec![1]);
    }

    /// Which methods read soft shadows' light samples: tlfr for soft shadows only; box never.
    #[test]
    fn light_samples_are_read_by_tlfr_for_soft_shadows_only() {
        let methods = resolve_methods(&["box".into(), "tlfr".into()], Effect::SoftShadow).unwrap();
        assert!(!methods[0].reads_light_samples(Effect::SoftShadow));
        assert!(methods[1].reads_light_samples(Effect::SoftShadow));
        let methods = resolve_methods(&["tlfr".into()], Effect::Dof).unwrap();
        assert!(!methods[0].reads_light_samples(Effect::Dof));
    }

    #[test]
    fn unknown_and_repeated_methods() {
        let error = resolve_methods(&["box".into(), "magic".into()], Effect::Indirect).err().unwrap().to_string();
        assert!(error.contains("magic") && error.contains("box"), "{error}");
        let methods = resolve_methods(&["box".into(), "box".into(), " ".into()], Effect::Indirect).unwrap();
        assert_eq!(methods.len(), 1);
    }

    /// On a glossy scene's indirect light `ilfr:grain=filter` and the screen-space filters are
    /// skipped by name with a reason, before tracing, and the other methods stay; on a diffuse
    /// scene, or for another effect, nothing is skipped.
    #[test]
    fn methods_that_blur_glossy_reflections_are_skipped_on_a_glossy_scene_and_the_rest_run() {
        let names = ["ilfr", "ilfr:grain=filter", "gif", "atrous", "oidn", "ilfr:grain=filter+oidn"];
        let resolve = || resolve_methods(&names.map(String::from), Effect::Indirect).unwrap();
        let (kept, skipped) = skip_blurring_on_glossy_scene(resolve(), Effect::Indirect, true);
        let kept: Vec<&str> = kept.iter().map(|m| m.name()).collect();
        assert_eq!(kept, ["ilfr", "oidn"]);
        let skipped_names: Vec<&str> = skipped.iter().map(|s| s.method.as_str()).collect();
        assert_eq!(skipped_names, ["ilfr:grain=filter", "gif", "atrous", "ilfr:grain=filter+oidn"]);
        assert!(skipped[0].reason.contains("glossy") && skipped[0].reason.contains("ilfr keeps them"), "{skipped:?}");
        let (kept, skipped) = skip_blurring_on_glossy_scene(resolve(), Effect::Indirect, false);
        assert_eq!((kept.len(), skipped.len()), (names.len(), 0));
        let methods = resolve_methods(&["gif".into()], Effect::Glossy).unwrap();
        assert_eq!(skip_blurring_on_glossy_scene(methods, Effect::Glossy, true).1.len(), 1);
    }
}
