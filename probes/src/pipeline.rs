//! The relight pipeline that every front end runs (`lfr probes relight` and `animate`,
//! `lfr compare`'s `probes`): the precompute read from its cache or built ([`obtain`]), the
//! transport dense or CPCA-compressed, read from its cache or compressed ([`operator`]), the
//! bounces after the first in CPCA's projected space when they fit in [`MAX_PROJECTED`] values
//! ([`projected_bounce`]), the camera's kept lookups ([`image_operator`]) and one relit frame
//! ([`relit_frame`]); [`frame_estimate`] is the peak memory of all of it. Long steps report
//! through `shading::progress` and the `step` callbacks; notes (a cache replaced, the bounces
//! run in full) go back to the caller to print.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use serde::Serialize;
use tracer::{Accel, Scene};

use crate::cache::CacheKey;
use crate::cpca::{Cpca, CpcaSettings, Precision};
use crate::direct::direct_irradiance;
use crate::error::CacheProblem;
use crate::frame::{indirect_timed, surfel_albedo, Indirect, ReceiverTransport, WithNearField};
use crate::image::{render_image, ImageSettings, ProbeImage};
use crate::image_operator::ImageOperator;
use crate::layout::Step;
use crate::memory::MemoryEstimate;
use crate::precompute::{Precompute, PrecomputeSettings, Stage};
use crate::projected_bounce::ProjectedBounce;
use crate::transport::Transport;
use crate::ProbesError;

/// The most projected values (Σ CPCA ranks) for the projected bounces: their matrix is 12 R²
/// bytes and takes about R² × (probes × coefficients) operations to form.
pub const MAX_PROJECTED: usize = 4096;

/// Whether [`obtain`] may replace a cache that cannot be used, or the error stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stale {
    Replace,
    Refuse,
}

/// The precompute and where it came from.
pub struct Obtained {
    pub precompute: Precompute,
    /// Read from the cache (true) or built and written there.
    pub from_cache: bool,
    /// Seconds to read or to build and write it.
    pub seconds: f64,
}

/// The name of a precompute stage, for progress messages.
pub fn stage_name(stage: Stage) -> &'static str {
    match stage {
        Stage::Layout(Step::Surfels) => "receivers (surfels)",
        Stage::Layout(Step::Placement) => "voxels, flood fill and probe placement",
        Stage::Layout(Step::Radius) => "support radius",
        Stage::Layout(Step::Coverage) => "coverage",
        Stage::Transport => "transport of every receiver (the long step)",
        Stage::Relight => "relight rays",
    }
}

/// The precompute of `scene` from `cache` when it holds this scene's, else built on `pool` and
/// written there; with [`Stale::Refuse`] a cache that cannot be used is an error, with
/// [`Stale::Replace`] it is rebuilt after `note` says why (a file that is not a cache or cannot
/// be read is always an error). `step` hears each step's name as it starts.
pub fn obtain(
    scene: &Scene,
    settings: &PrecomputeSettings,
    cache: &Path,
    stale: Stale,
    pool: &rayon::ThreadPool,
    step: &(dyn Fn(&str) + Sync),
    note: &mut dyn FnMut(String),
) -> Result<Obtained, ProbesError> {
    let key = CacheKey::of(scene, settings);
    let t = Instant::now();
    if std::fs::symlink_metadata(cache).is_ok() {
        step("reading the cache");
        match crate::cache::read(cache, &key, settings) {
            Ok(precompute) => return Ok(Obtained { precompute, from_cache: true, seconds: t.elapsed().as_secs_f64() }),
            Err(ProbesError::Cache { problem, .. })
                if stale == Stale::Replace && !matches!(problem, CacheProblem::NotACache | CacheProblem::Io) =>
            {
                note(format!("{} cannot be used: {problem}; building it again", cache.display()));
            }
            Err(e) => return Err(e),
        }
    }
    let precompute = pool.install(|| Precompute::build(scene, settings, &mut |stage| step(stage_name(stage))))?;
    step("writing the cache");
    crate::cache::write(cache, &key, &precompute)?;
    Ok(Obtained { precompute, from_cache: false, seconds: t.elapsed().as_secs_f64() })
}

/// The dense transports or their CPCA compression.
pub enum Operator<'a> {
    Dense(&'a Vec<Transport>),
    Cpca(Cpca),
}

impl Operator<'_> {
    pub fn transport(&self) -> &dyn ReceiverTransport {
        match self {
            Operator::Dense(t) => *t,
            Operator::Cpca(c) => c,
        }
    }
}

/// The compressed transport's figures, for reports.
#[derive(Serialize, Clone, Debug)]
pub struct CpcaReport {
    pub clusters: usize,
    pub mean_coefficients: f64,
    pub max_cluster_error: f64,
    pub tolerance: f64,
    pub fp16: bool,
    pub bytes: usize,
    pub bytes_per_receiver: f64,
    /// Seconds to compress, or to read from the cache.
    pub compress_s: f64,
    pub from_cache: bool,
    pub cache: String,
}

/// The compressed transport's cache beside the precompute's: `CACHE.cpca`.
pub fn cpca_path(cache: &Path) -> PathBuf {
    let mut name = cache.as_os_str().to_os_string();
    name.push(".cpca");
    PathBuf::from(name)
}

/// The dense transports, or with `settings` their CPCA compression, read from [`cpca_path`]
/// when it holds this one (keyed by the precompute's key and the CPCA settings), else
/// compressed and written there. A compressed transport of other settings, geometry or format
/// version is replaced (one file per precompute cache) after `note` says so; a damaged one or
/// another file is an error naming it.
pub fn operator<'a>(
    pre: &'a Precompute,
    settings: Option<CpcaSettings>,
    pool: &rayon::ThreadPool,
    cache: &Path,
    key: &CacheKey,
    note: &mut dyn FnMut(String),
) -> Result<(Operator<'a>, Option<CpcaReport>), ProbesError> {
    let Some(settings) = settings else {
        return Ok((Operator::Dense(&pre.transports), None));
    };
    let t = Instant::now();
    let path = cpca_path(cache);
    let ckey = crate::cache::cpca_key(key, &settings);
    let cached = match std::fs::symlink_metadata(&path) {
        Err(_) => None,
        Ok(_) => match crate::cache::read_cpca(&path, &ckey, &settings, pre) {
            Ok(cpca) => Some(cpca),
            Err(ProbesError::Cache { problem, .. })
                if matches!(
                    problem,
                    CacheProblem::OtherSettings | CacheProblem::OtherGeometry | CacheProblem::Version
                ) =>
            {
                note(format!("{} holds another compression ({problem}); replacing it", path.display()));
                None
            }
            Err(e) => return Err(e),
        },
    };
    let from_cache = cached.is_some();
    let cpca = match cached {
        Some(cpca) => cpca,
        None => {
            let positions: Vec<Vec3> = pre.surfels.surfels.iter().map(|s| s.position).collect();
            let cpca = pool.install(|| Cpca::build(&pre.transports, &positions, pre.coefficients(), &settings))?;
            crate::cache::write_cpca(&path, &ckey, &cpca)?;
            cpca
        }
    };
    let report = CpcaReport {
        clusters: cpca.clusters.len(),
        mean_coefficients: cpca.mean_rank(),
        max_cluster_error: cpca.clusters.iter().map(|c| c.error).fold(0.0, f64::max),
        tolerance: settings.tolerance,
        fp16: settings.precision == Precision::F16,
        bytes: cpca.bytes(),
        bytes_per_receiver: cpca.bytes() as f64 / pre.surfels.surfels.len().max(1) as f64,
        compress_s: t.elapsed().as_secs_f64(),
        from_cache,
        cache: path.display().to_string(),
    };
    Ok((Operator::Cpca(cpca), Some(report)))
}

/// The probes' bounces for a path tracer's `max_bounces`: the path tracer counts the bounce that
/// brings the direct light, the probes only the indirect ones after it, so `max_bounces − 1`,
/// at least 1. `lfr probes relight` and `lfr compare` both stop there (or sooner by the
/// tolerance), so that the same settings give the same image.
pub fn indirect_bounces(max_bounces: u32) -> usize {
    max_bounces.saturating_sub(1).max(1) as usize
}

/// The projected bounce's figures, for reports.
#[derive(Serialize, Clone, Copy, Debug)]
pub struct ProjectedReport {
    pub size: usize,
    pub bytes: usize,
    pub build_s: f64,
}

/// The bounces after the first in CPCA's projected space: formed once per run (the matrix
/// depends on the albedo of `lit`, not on its light) when `op` is CPCA and its projected values
/// are at most [`MAX_PROJECTED`]; `None` for the dense transport, and `None` after `note` says
/// why when there are more (the bounces then run in full).
pub fn projected_bounce(
    op: &Operator,
    lit: &Scene,
    pre: &Precompute,
    pool: &rayon::ThreadPool,
    note: &mut dyn FnMut(String),
) -> Result<Option<(ProjectedBounce, ProjectedReport)>, ProbesError> {
    let Operator::Cpca(cpca) = op else { return Ok(None) };
    let size: usize = cpca.clusters.iter().map(|c| c.rank).sum();
    if size > MAX_PROJECTED {
        note(format!("{size} projected values (over {MAX_PROJECTED}): the bounces run in full"));
        return Ok(None);
    }
    let t = Instant::now();
    let albedo = pool.install(|| surfel_albedo(lit, &pre.surfels));
    let projected = pool.install(|| ProjectedBounce::build(cpca, &pre.table, &albedo))?;
    let report = ProjectedReport { size: projected.size, bytes: projected.bytes(), build_s: t.elapsed().as_secs_f64() };
    Ok(Some((projected, report)))
}

/// One relit frame's seconds, split as the paper's Table 2 (scene relight, probe relight,
/// cluster projection, receiver irradiance), plus the image.
#[derive(Serialize, Clone, Copy, Debug)]
pub struct FrameTimes {
    /// Scene relight: direct light at the senders.
    pub direct_s: f64,
    /// The bounces, all three stages below together.
    pub bounces_s: f64,
    /// Probe relight (sender radiance, the relight rays' SH and the fit), summed over the
    /// bounces.
    pub probe_relight_s: f64,
    /// Cluster projection (CPCA only), summed over the bounces.
    pub cluster_projection_s: f64,
    /// Receiver irradiance (and the clamp and convergence test), summed over the bounces.
    pub receiver_irradiance_s: f64,
    /// The bounces after the first in CPCA's projected space (all three stages at once), when
    /// they run there.
    pub projected_bounces_s: f64,
    /// The near field's gather from the senders, summed over the bounces (0 when it is off).
    pub near_field_s: f64,
    pub iterations: usize,
    /// The image from the receivers: the kept lookups' weighted sums when the camera's image
    /// operator was built, else primary rays and lookups.
    pub image_s: f64,
    /// Direct light at the senders and the bounces: the relit frame without the image.
    pub frame_s: f64,
}

/// How a frame's bounces run: in CPCA's projected space after the first, or every one through
/// the relight rays and the receivers' transport.
pub enum Bounces<'a> {
    Projected { projected: &'a ProjectedBounce, cpca: &'a Cpca },
    Full(&'a dyn ReceiverTransport),
}

impl<'a> Bounces<'a> {
    /// The projected bounces when `projected` is given (it is built only for CPCA), else full
    /// bounces through `op`.
    pub fn of(op: &'a Operator, projected: Option<&'a ProjectedBounce>) -> Bounces<'a> {
        match (op, projected) {
            (Operator::Cpca(cpca), Some(projected)) => Bounces::Projected { projected, cpca },
            (op, _) => Bounces::Full(op.transport()),
        }
    }
}

/// What one frame does after the light changes.
pub struct FrameSettings<'a> {
    /// At most this many bounces (from `start` when given, else from zero).
    pub bounces: usize,
    pub start: Option<&'a [Vec3]>,
    /// The bounces stop when the largest change falls under this share of the largest
    /// irradiance (0: all of them).
    pub tolerance: f32,
    /// Shadow rays per sender for the direct light.
    pub light_samples: u32,
}

/// One relit frame of `lit`: direct light at the senders, the bounces, the image (through
/// `camera`'s kept lookups when given, which must be built for `image`; else traced and looked
/// up).
#[allow(clippy::too_many_arguments)]
pub fn relit_frame(
    lit: &Scene,
    accel: &Accel,
    pre: &Precompute,
    bounces: &Bounces,
    frame: &FrameSettings,
    image: &ImageSettings,
    camera: Option<&ImageOperator>,
    pool: &rayon::ThreadPool,
) -> Result<(Indirect, ProbeImage, FrameTimes), ProbesError> {
    if let Some(camera) = camera {
        if camera.settings != *image {
            return Err(ProbesError::parameter("image", "the camera's image operator was built for other settings"));
        }
    }
    pool.install(|| {
        let albedo = surfel_albedo(lit, &pre.surfels);
        let scale = pre.scale as f32;
        let t = Instant::now();
        let direct = direct_irradiance(lit, accel, &pre.surfels, frame.light_samples, image.seed, scale)?;
        let direct_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let (out, split) = match bounces {
            Bounces::Projected { projected, cpca } => projected.indirect_with_near(
                cpca,
                pre.near.as_ref(),
                &pre.table,
                &albedo,
                &direct,
                frame.start,
                frame.bounces,
                frame.tolerance,
            )?,
            Bounces::Full(far) => {
                let with_near;
                let transport: &dyn ReceiverTransport = match &pre.near {
                    Some(near) => {
                        with_near = WithNearField { far: *far, near };
                        &with_near
                    }
                    None => *far,
                };
                indirect_timed(transport, &pre.table, &albedo, &direct, frame.start, frame.bounces, frame.tolerance)?
            }
        };
        let bounces_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let img = match camera {
            Some(camera) => camera.render(lit, accel, &out.irradiance)?,
            None => render_image(lit, accel, pre, &out.irradiance, image)?,
        };
        let image_s = t.elapsed().as_secs_f64();
        let times = FrameTimes {
            direct_s,
            bounces_s,
            probe_relight_s: split.probe_relight_s,
            cluster_projection_s: split.cluster_projection_s,
            receiver_irradiance_s: split.receiver_irradiance_s,
            projected_bounces_s: split.projected_bounces_s,
            near_field_s: split.near_field_s,
            iterations: out.iterations,
            image_s,
            frame_s: direct_s + bounces_s,
        };
        Ok((out, img, times))
    })
}

/// The camera's image operator (the lookups kept for every frame) and its build seconds.
pub fn image_operator(
    lit: &Scene,
    accel: &Accel,
    pre: &Precompute,
    image: &ImageSettings,
    pool: &rayon::ThreadPool,
) -> Result<(ImageOperator, f64), ProbesError> {
    let t = Instant::now();
    let camera = pool.install(|| ImageOperator::build(lit, accel, pre, image))?;
    Ok((camera, t.elapsed().as_secs_f64()))
}

/// The peak memory of a relit frame: the precompute or its cache, CPCA and the projected
/// bounce when asked for, and the image with its kept lookups.
pub fn frame_estimate(
    settings: &PrecomputeSettings,
    cpca: Option<&CpcaSettings>,
    projected: bool,
    image: &ImageSettings,
    threads: usize,
) -> MemoryEstimate {
    let mut e = MemoryEstimate::precompute(settings, threads);
    if let Some(cpca) = cpca {
        e = e.with_cpca(settings, cpca, threads, projected.then_some(MAX_PROJECTED));
    }
    e.with_image(image.width, image.height, image.pixel_samples)
}

/// The share of the image ([`crate::image::specular_share`]) on metallic and glossy surfaces
/// from which the front ends warn: 1 % of the pixels.
pub const SPECULAR_WARNING_SHARE: f64 = 0.01;

/// The warning for an image with `share` of its pixels on surfaces whose specular lobe
/// outweighs the diffuse one, from [`SPECULAR_WARNING_SHARE`] up; `None` below it.
pub fn specular_warning(share: f64) -> Option<String> {
    (share >= SPECULAR_WARNING_SHARE).then(|| {
        format!(
            "{:.1} % of the image sees metallic or glossy surfaces (specular lobe stronger than the diffuse one); the \
             probes carry diffuse light only, so the indirect light reflected there is missing (too dark against \
             path tracing)",
            100.0 * share
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_probes_bounce_the_path_tracers_indirect_bounces() {
        let bounces: Vec<usize> = [0, 1, 2, 5].into_iter().map(indirect_bounces).collect();
        assert_eq!(bounces, [1, 1, 1, 4], "one bounce at least; else one fewer than the path's");
    }

    #[test]
    fn the_specular_warning_starts_at_one_percent_and_gives_the_share() {
        assert_eq!(specular_warning(0.0), None);
        assert_eq!(specular_warning(0.009), None);
        let warning = specular_warning(0.5).expect("half the image");
        assert!(warning.starts_with("50.0 % of the image") && warning.contains("missing"), "{warning}");
        assert!(specular_warning(SPECULAR_WARNING_SHARE).is_some());
    }
}
