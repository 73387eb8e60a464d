//! `lfr reconstruct`: the temporal light field reconstruction of a `lens-time` sample file into
//! an image, optionally refocused after the fact (a new focus distance and lens radius; the
//! paper's Section 6), as a linear EXR and a PNG preview beside it.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use recon::tlfr::global_illumination::{GiMode, DEFAULT_GI_RADIUS};
use recon::tlfr::method::reconstruct_file;
use recon::tlfr::settings::Kernel;
use recon::tlfr::settings::TlfrSettings;
use tracer::output::{write_exr, write_png, Layer};

use tracer::limits::MAX_RECON_RAYS;

use crate::common::RunArgs;
use crate::convert::rgb_channels;

#[derive(clap::Args)]
pub struct ReconstructArgs {
    /// A `lens-time` sample file (`lfr dump --kind lens-time`).
    #[arg(long)]
    samples: PathBuf,
    /// Reconstruction locations per pixel (at most; a pixel whose first 16 locations all see
    /// one surface and agree stops there, docs/tlfr.md, unless --fixed-locations).
    #[arg(long, default_value_t = 128)]
    locations: u32,
    /// Every pixel takes all --locations (the adaptive rule off).
    #[arg(long)]
    fixed_locations: bool,
    /// Evaluate each location with the per-location code (`recon::tlfr::query`) that the fused
    /// kernel is tested against, instead of the fused kernel.
    #[arg(long)]
    oracle: bool,
    /// Refocus: the new focus distance (scene units); needs --aperture.
    #[arg(long)]
    focus_distance: Option<f32>,
    /// Refocus: the new lens radius (scene units); needs --focus-distance.
    #[arg(long)]
    aperture: Option<f32>,
    /// The bandwidth extension (paper Figure 14): weight each sample of a glossy surface by a
    /// Gaussian in view angle of deviation SCALE · 8/κ (κ from the file's `bandwidth`; 8/κ is
    /// the reflected lobe's deviation; without a value 0.5, docs/tlfr.md). Off unless given.
    #[arg(long, value_name = "SCALE", num_args = 0..=1, default_missing_value = "0.5")]
    bandwidth: Option<f32>,
    /// Full global illumination: reconstruct only each sample's `direct` part (the file must
    /// have it: `lfr dump --fields ...,direct`) and add the rest of the radiance averaged per
    /// pixel and smoothed over RADIUS pixels among pixels of similar depth (docs/tlfr.md, "Full
    /// global illumination"; without a value the default radius). Off unless given.
    #[arg(long, value_name = "RADIUS")]
    gi_split: Option<Option<u32>>,
    #[command(flatten)]
    run: RunArgs,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Output EXR; the PNG preview goes beside it.
    #[arg(long)]
    out: PathBuf,
}

pub fn run(args: &ReconstructArgs) -> Result<()> {
    if args.out.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("exr")) != Some(true) {
        bail!("--out {}: the output must be an .exr file", args.out.display());
    }
    let preview = crate::outputs::preview_of(&args.out);
    crate::outputs::OutputPlan::new()
        .file(&args.out, "--out")
        .file(&preview, "the PNG preview beside --out")
        .input(&args.samples, "--samples")
        .check()?;
    if args.locations == 0 || args.locations > MAX_RECON_RAYS {
        bail!("--locations must be in 1..={MAX_RECON_RAYS}, got {}", args.locations);
    }
    let refocus = match (args.focus_distance, args.aperture) {
        (Some(distance), _) if !(distance.is_finite() && distance > 0.0) => {
            bail!("--focus-distance must be positive and finite, got {distance}")
        }
        (_, Some(aperture)) if !(aperture.is_finite() && aperture >= 0.0) => {
            bail!("--aperture must be finite and at least 0, got {aperture}")
        }
        (Some(distance), Some(aperture)) => Some((distance, aperture)),
        (None, None) => None,
        _ => bail!("--focus-distance and --aperture go together"),
    };
    if let Some(scale) = args.bandwidth {
        if !(scale.is_finite() && scale > 0.0) {
            bail!("--bandwidth must be a positive, finite scale, got {scale}");
        }
    }
    let settings = TlfrSettings {
        locations: args.locations,
        refocus,
        seed: args.run.seed_or(0),
        bandwidth_scale: args.bandwidth,
        adaptive: if args.fixed_locations { None } else { TlfrSettings::default().adaptive },
        gi: match args.gi_split {
            Some(Some(radius)) if radius > 64 => bail!("--gi-split takes a radius in 0..=64 pixels, got {radius}"),
            Some(radius) => GiMode::Split { radius: radius.unwrap_or(DEFAULT_GI_RADIUS) },
            None => GiMode::Whole,
        },
        kernel: if args.oracle { Kernel::Oracle } else { Kernel::Fused },
    };
    let pool = args.run.worker_pool()?;
    // Memory before any work: the sample count from the file's header
    // (the full check of its chunks follows in `reconstruct_file`).
    let samples =
        sampleio::SampleFile::open_unchecked(&args.samples).map_err(|e| anyhow::anyhow!("{}", e))?.len() as u64;
    tracer::memory::check(
        &format!("reconstructing the {samples} samples of {}", args.samples.display()),
        samples * recon::tlfr::method::BYTES_PER_SAMPLE,
    )?;
    let bar = if args.quiet { indicatif::ProgressBar::hidden() } else { indicatif::ProgressBar::new_spinner() };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let message = format!("tlfr, {} locations per pixel", args.locations);
    let output = crate::common::with_stage_progress(&bar, &message, || {
        pool.install(|| reconstruct_file(&args.samples, &settings))
    });
    bar.finish_and_clear();
    let output = output.map_err(|e| {
        // Errors about the file name it first; prefix the others (settings) with it, once.
        let (message, path) = (e.to_string(), args.samples.display().to_string());
        if message.starts_with(&path) {
            anyhow::anyhow!(message)
        } else {
            anyhow::anyhow!("{path}: {message}")
        }
    })?;
    let image = &output.image;
    write_exr(&args.out, image.width, image.height, &[Layer { name: "", channels: rgb_channels(image) }])
        .with_context(|| format!("writing {}", args.out.display()))?;
    let pixels: Vec<glam::Vec3> = image.pixels.iter().map(|p| glam::Vec3::from_array(*p)).collect();
    write_png(&preview, image.width, image.height, &pixels, 1.0)
        .with_context(|| format!("writing {}", preview.display()))?;
    println!(
        "reconstructed {} at {}x{} with {} locations per pixel: preprocess {:.3} s, reconstruction {:.3} s",
        args.samples.display(),
        image.width,
        image.height,
        args.locations,
        output.preprocess_s,
        output.recon_s
    );
    for note in &output.notes {
        match note.strip_prefix(recon::method::WARNING) {
            Some(warning) => eprintln!("warning: {warning}"),
            None => println!("  {note}"),
        }
    }
    println!("wrote {} and {}", args.out.display(), preview.display());
    Ok(())
}
