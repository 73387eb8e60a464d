//! The one set of defaults of the technique, read by `lfr probes stats/precompute/relight/
//! animate` (their flags' defaults) and by `lfr compare`'s method `probes` (its options'
//! defaults), so that "the defaults" give one image whichever front end runs them.
//!
//! Each value is the measured best at equal time where it was measured (docs/probes.md,
//! "Choices beyond the paper"): on Cornell 128², 4× the receivers changed PSNR by ±0.03 dB at
//! 1.5–2.5× the precompute; 16 primary rays per pixel gave 35.07 dB against 33.2 dB with 4 and
//! was 118× path tracing per frame; CPCA cost 0.07 dB and halved the bounces' time; a relight
//! fit that weights escaped rays at 0.01 instead of the paper's 1 brought the image from 0.90 to
//! 0.97 of the path tracer's brightness. The paper's own settings remain options (`miss_weight=1`,
//! `cpca=off`, `reconstruction=spatial`, `--candidates paper`).

/// Probes placed (Section 4.1).
pub const PROBES: usize = 64;
/// Receiver budget (surfels; the count comes close to it).
pub const RECEIVERS: usize = 20_000;
/// N_overlap: mean number of probes covering a receiver.
pub const OVERLAP: f64 = 10.0;
/// SH order of the probes (the paper's 7).
pub const ORDER: usize = 7;
/// Directions per receiver of the transport (M).
pub const DIRECTIONS: u32 = 512;
/// Relight rays per probe.
pub const RELIGHT_RAYS: u32 = 8000;
/// Weight of escaped relight rays in each probe's SH fit (1: the paper's projection).
pub const MISS_WEIGHT: f64 = 0.01;
/// Light samples per sender and per primary ray for the direct light.
pub const LIGHT_SAMPLES: u32 = 16;
/// Primary rays per pixel of the image.
pub const PIXEL_SAMPLES: u32 = 16;
/// The transport is compressed with CPCA (Eq. 11) before relighting.
pub const CPCA: bool = true;
/// CPCA's U and W stored in fp16 (`fp16`; the near field's weights are fp16 whatever it says).
/// Measured (docs/probes.md, 2026-12-08): the same PSNR as f32 on Sponza, Cornell and the
/// bunny, and under 600 B per receiver on all three (Sponza 953 B with f32).
pub const FP16: bool = true;
/// The bounces stop when the largest change and the tail it predicts fall under this share of
/// the largest irradiance (when the bounce count is not given).
pub const BOUNCE_TOLERANCE: f32 = 1e-3;
/// The near field (`near_field`): hits nearer than [`NEAR_RADIUS`] support radii gathered from
/// their senders directly, the rest through the probes. The front ends' default; the crate's
/// `TransportSettings::default()` is the paper's transport (off). Measured (docs/probes.md):
/// at 0.25 Cornell +1.9 dB, the bunny +1.2 dB, Sponza +0.5 dB, within 600 B per receiver
/// with CPCA on all three; 0.5 gains more on Cornell but takes Sponza to 717 B.
pub const NEAR_FIELD: bool = true;
/// The near field's radius, a share of the probes' support radius.
pub const NEAR_RADIUS: f64 = 0.25;
/// Relight hits read no hidden sender beside a valid one (`RelightTable::drop_hidden_senders`).
/// Measured with the near field at 0.25 r (docs/probes.md): Sponza +1.05 dB, Cornell +0.17 dB,
/// the bunny ±0 (without the near field Cornell lost 0.14 dB).
pub const DROP_HIDDEN_SENDERS: bool = true;
