//! The flags that `lfr probes`' subcommands share: the receivers and the placement (`stats`,
//! `precompute`), the precompute and its cache (`precompute`, `relight`, `animate`) and how a
//! frame is lit and computed (`relight`, `animate`). Their defaults are `probes::defaults`, the
//! same as `lfr compare`'s `probes` (tested below).

use std::path::PathBuf;

use anyhow::Result;
use probes::cpca::{CpcaSettings, Precision};
use probes::defaults;
use probes::placement::{CandidateRule, PlacementSettings};
use probes::precompute::{Precompute, PrecomputeSettings};
use probes::surfels::{Sides, SurfelSettings};
use probes::transport::TransportSettings;

/// Which empty voxels may hold a probe.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub(super) enum Candidates {
    /// Next to a surface that faces the voxel (default; an extension of the paper).
    Front,
    /// Next to any surface (the paper's rule).
    Paper,
}

/// Which surface sides get receivers (`probes::surfels::Sides`).
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub(super) enum SidesArg {
    /// The sides the side test does not hide, the budget spent on their area (default).
    Valid,
    /// As `valid`, and not the sides whose test rays all escape.
    Seeing,
    /// Both sides of every surface (before 2026-12-08).
    All,
}

/// Receivers and probe placement, shared by `stats` and `precompute`.
#[derive(clap::Args, Clone, Debug)]
pub struct PlacementArgs {
    /// Number of probes.
    #[arg(long, default_value_t = defaults::PROBES)]
    pub(super) probes: usize,
    /// Receiver budget (surfels; the count comes close to it).
    #[arg(long, default_value_t = defaults::RECEIVERS)]
    pub(super) receivers: usize,
    /// N_overlap: mean number of probes covering a receiver (sets the support radius).
    #[arg(long, default_value_t = defaults::OVERLAP)]
    pub(super) overlap: f64,
    /// Candidate rule for probe positions.
    #[arg(long, value_enum, default_value_t = Candidates::Front)]
    pub(super) candidates: Candidates,
    /// Which surface sides get receivers.
    #[arg(long, value_enum, default_value_t = SidesArg::Valid)]
    pub(super) sides: SidesArg,
}

impl PlacementArgs {
    /// The receivers' and the placement's settings.
    pub(super) fn settings(&self, seed: u32) -> (SurfelSettings, PlacementSettings) {
        let rule = match self.candidates {
            Candidates::Front => CandidateRule::FrontFacing,
            Candidates::Paper => CandidateRule::Paper,
        };
        (
            SurfelSettings {
                budget: self.receivers,
                seed,
                sides: match self.sides {
                    SidesArg::Valid => Sides::Valid,
                    SidesArg::Seeing => Sides::Seeing,
                    SidesArg::All => Sides::All,
                },
                ..Default::default()
            },
            PlacementSettings { probes: self.probes, overlap: self.overlap, rule },
        )
    }
}

/// A boolean default as its flag's value (`--cpca=on|off`).
const fn on_off(value: bool) -> &'static str {
    if value {
        "on"
    } else {
        "off"
    }
}

/// The precompute's settings and its cache, shared by `precompute`, `relight` and `animate`.
#[derive(clap::Args, Clone, Debug)]
pub struct PrecomputeOptions {
    /// The precompute cache file (keyed by geometry and these settings, never by lights or
    /// albedo).
    #[arg(long)]
    pub(super) cache: PathBuf,
    #[command(flatten)]
    pub(super) placement: PlacementArgs,
    /// SH order of the probes (0 to 7).
    #[arg(long, default_value_t = defaults::ORDER)]
    pub(super) order: usize,
    /// Directions per receiver of the transport.
    #[arg(long, default_value_t = defaults::DIRECTIONS)]
    pub(super) directions: u32,
    /// Relight rays per probe.
    #[arg(long, default_value_t = defaults::RELIGHT_RAYS)]
    pub(super) relight_rays: u32,
    /// Gather the hits nearer than --near-radius from their senders directly, the rest through
    /// the probes (`--near-field=off`: every hit through the probes, the paper's transport).
    #[arg(long, value_name = "on|off", num_args = 0..=1, require_equals = true,
        default_value = on_off(defaults::NEAR_FIELD), default_missing_value = "on",
        value_parser = clap::builder::BoolishValueParser::new())]
    pub(super) near_field: bool,
    /// The near field's radius, a share of the probes' support radius.
    #[arg(long, default_value_t = defaults::NEAR_RADIUS)]
    pub(super) near_radius: f64,
}

impl PrecomputeOptions {
    pub(super) fn settings(&self, seed: u32) -> PrecomputeSettings {
        let (surfels, placement) = self.placement.settings(seed);
        PrecomputeSettings {
            surfels,
            placement,
            transport: TransportSettings {
                order: self.order,
                directions: self.directions,
                seed,
                near: self.near_field.then_some(self.near_radius),
                ..Default::default()
            },
            relight_rays: self.relight_rays,
        }
    }
}

/// How a frame is lit and computed (`relight`, `animate`).
#[derive(clap::Args, Clone, Debug)]
pub struct FrameOptions {
    /// Remove the scene's own lights (point, spot and directional lights, emission, the
    /// environment) before adding the point light of --light-position (or the animated one).
    #[arg(long)]
    pub(super) no_scene_lights: bool,
    /// Radiant intensity of the added point light (W/sr), one value or R,G,B; default
    /// (extent / 2)², which gives an irradiance of 1 at half the scene's largest extent.
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "V|R,G,B", allow_negative_numbers = true)]
    pub(super) light_intensity: Option<Vec<f32>>,
    /// Light samples per sender and per primary ray for the direct light.
    #[arg(long, default_value_t = defaults::LIGHT_SAMPLES)]
    pub(super) light_samples: u32,
    /// Primary rays per pixel (1: through the centre; more: stratified, averaged).
    #[arg(long, default_value_t = defaults::PIXEL_SAMPLES)]
    pub(super) pixel_samples: u32,
    /// Compress the transport with CPCA before relighting (`--cpca=off`: the dense transport).
    #[arg(long, value_name = "on|off", num_args = 0..=1, require_equals = true, default_value = on_off(defaults::CPCA),
        default_missing_value = "on", value_parser = clap::builder::BoolishValueParser::new())]
    pub(super) cpca: bool,
    /// CPCA: the largest relative residual energy per cluster.
    #[arg(long, default_value_t = CpcaSettings::default().tolerance)]
    pub(super) cpca_tolerance: f64,
    /// CPCA: the most coefficients per cluster.
    #[arg(long, default_value_t = CpcaSettings::default().max_coefficients)]
    pub(super) cpca_coefficients: usize,
    /// CPCA: clusters hold fewer receivers than this.
    #[arg(long, default_value_t = CpcaSettings::default().cluster_limit)]
    pub(super) cpca_cluster_limit: usize,
    /// CPCA: store the compressed transport in fp16 (`--fp16=off`: f32). Default: on with CPCA.
    #[arg(long, value_name = "on|off", num_args = 0..=1, require_equals = true,
        default_missing_value = "on", value_parser = clap::builder::BoolishValueParser::new())]
    pub(super) fp16: Option<bool>,
    /// Weight of the relight rays that escape (or hit a lookup hole) in each probe's SH fit:
    /// 1 is the paper's projection (radiance zero along them); smaller fits the SH to the hit
    /// rays only, which are the only directions a receiver reads a probe in (docs/probes.md:
    /// Cornell's image 0.90 → 0.97 as bright as the path tracer's).
    #[arg(long, default_value_t = defaults::MISS_WEIGHT)]
    pub(super) relight_miss_weight: f64,
    /// Unseen directions (hits no covering probe sees) take the mean of the receiver's seen
    /// ones instead of zero (the paper's): its transport scaled by hits / seen hits.
    #[arg(long)]
    pub(super) renormalise_unseen: bool,
    /// Drop hidden senders (no transport; mostly inside geometry) from relight hits that also
    /// read valid ones (docs/probes.md: Sponza's one-bounce gather at the camera's hits 0.62 →
    /// 0.87 of the exact direct light there; with the near field Sponza +1.05 dB, Cornell
    /// +0.17 dB); `--drop-hidden-senders=off` keeps them.
    #[arg(long, value_name = "on|off", num_args = 0..=1, require_equals = true,
        default_value = on_off(defaults::DROP_HIDDEN_SENDERS), default_missing_value = "on",
        value_parser = clap::builder::BoolishValueParser::new())]
    pub(super) drop_hidden_senders: bool,
}

impl FrameOptions {
    /// The CPCA settings (when --cpca) and the added light's intensity, checked.
    /// Applies the run-time choices that change the precompute's use, not its cache: the
    /// relight fit and the unseen directions' fill.
    pub(super) fn apply(&self, pre: &mut Precompute, pool: &rayon::ThreadPool) -> Result<()> {
        if self.drop_hidden_senders {
            pre.drop_hidden_senders()?;
        }
        if self.relight_miss_weight < 1.0 {
            pool.install(|| pre.table.fit(self.relight_miss_weight))?;
        }
        if self.renormalise_unseen {
            if pre.near.is_some() {
                anyhow::bail!(
                    "renormalise-unseen: scales α by all hits over the seen ones, which the near field's hits are not"
                );
            }
            pre.transports.iter_mut().for_each(|t| t.renormalise_unseen());
        }
        Ok(())
    }

    pub(super) fn validated(&self) -> Result<(Option<CpcaSettings>, Option<glam::Vec3>)> {
        if self.light_samples == 0 || self.light_samples > probes::direct::MAX_SAMPLES {
            anyhow::bail!(
                "light-samples: must be between 1 and {}, got {}",
                probes::direct::MAX_SAMPLES,
                self.light_samples
            );
        }
        let intensity = match self.light_intensity.as_deref() {
            None => None,
            Some(v) => {
                let c = match v {
                    [g] => glam::Vec3::splat(*g),
                    [r, g, b] => glam::Vec3::new(*r, *g, *b),
                    _ => anyhow::bail!("light-intensity: takes one value or three (R,G,B), got {}", v.len()),
                };
                if !c.is_finite() || c.min_element() < 0.0 {
                    anyhow::bail!("light-intensity: must be finite and non-negative, got {v:?}");
                }
                Some(c)
            }
        };
        if !(1..=probes::image::MAX_PIXEL_SAMPLES).contains(&self.pixel_samples) {
            anyhow::bail!(
                "pixel-samples: must be between 1 and {}, got {}",
                probes::image::MAX_PIXEL_SAMPLES,
                self.pixel_samples
            );
        }
        if self.fp16 == Some(true) && !self.cpca {
            anyhow::bail!("fp16: stores the CPCA-compressed transport, which --cpca=off turns off");
        }
        let fp16 = self.fp16.unwrap_or(defaults::FP16);
        if !(self.relight_miss_weight > 0.0 && self.relight_miss_weight <= 1.0) {
            anyhow::bail!(
                "relight-miss-weight: must be in (0, 1] (1: the paper's projection), got {}",
                self.relight_miss_weight
            );
        }
        if self.renormalise_unseen && self.cpca {
            anyhow::bail!("renormalise-unseen: applies to the dense transport only (the CPCA cache holds the paper's); add --cpca=off");
        }
        let cpca = CpcaSettings {
            cluster_limit: self.cpca_cluster_limit,
            tolerance: self.cpca_tolerance,
            max_coefficients: self.cpca_coefficients,
            precision: if fp16 { Precision::F16 } else { Precision::F32 },
        };
        cpca.validate()?;
        Ok((self.cpca.then_some(cpca), intensity))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compare::probes_method::ProbesMethod;
    use clap::Parser;

    /// `lfr probes relight`'s precompute and frame flags, alone.
    #[derive(Parser)]
    struct RelightFlags {
        #[command(flatten)]
        pre: PrecomputeOptions,
        #[command(flatten)]
        frame: FrameOptions,
    }

    #[test]
    fn relight_and_compare_run_the_same_defaults() {
        let seed = 7;
        let cli = RelightFlags::try_parse_from(["relight", "--cache", "c.probes"]).unwrap();
        let method = ProbesMethod::parse("probes", seed).unwrap().unwrap();
        assert_eq!(cli.pre.settings(seed), method.precompute);
        let (cpca, intensity) = cli.frame.validated().unwrap();
        assert_eq!(cpca, method.cpca);
        assert!(cpca.is_some() && intensity.is_none());
        assert_eq!(cli.frame.pixel_samples, method.pixel_samples);
        assert_eq!(cli.frame.light_samples, method.light_samples);
        assert_eq!(cli.frame.relight_miss_weight, method.miss_weight);
        assert_eq!(cli.frame.drop_hidden_senders, method.drop_hidden_senders);
    }

    #[test]
    fn the_near_field_flags_and_options_give_the_same_settings() {
        let seed = 2;
        for (flags, spec) in [
            (&[][..], "probes"),
            (&[][..], "probes:near_field=on:near_radius=0.25"),
            (&["--near-field=off"][..], "probes:near_field=off"),
            (&["--near-field=off", "--near-radius", "0.3"][..], "probes:near_field=off:near_radius=0.3"),
            (&["--near-field", "--near-radius", "0.3"][..], "probes:near_field=on:near_radius=0.3"),
            (&["--near-field=on"][..], "probes:near_field=on"),
        ] {
            let mut argv = vec!["relight", "--cache", "c.probes"];
            argv.extend_from_slice(flags);
            let cli = RelightFlags::try_parse_from(argv).unwrap();
            let method = ProbesMethod::parse(spec, seed).unwrap().unwrap();
            assert_eq!(cli.pre.settings(seed), method.precompute, "{flags:?}");
        }
        let on = ProbesMethod::parse("probes:near_field=on:near_radius=0.3", seed).unwrap().unwrap();
        assert_eq!(on.precompute.transport.near, Some(0.3));
        assert!(ProbesMethod::parse("probes:near_field=on:near_radius=5", seed).is_err());
    }

    #[test]
    fn the_sides_flag_and_option_give_the_same_settings() {
        let seed = 3;
        for (flags, spec, sides) in [
            (&[][..], "probes", Sides::Valid),
            (&["--sides", "valid"][..], "probes:sides=valid", Sides::Valid),
            (&["--sides", "seeing"][..], "probes:sides=seeing", Sides::Seeing),
            (&["--sides", "all"][..], "probes:sides=all", Sides::All),
        ] {
            let mut argv = vec!["relight", "--cache", "c.probes"];
            argv.extend_from_slice(flags);
            let cli = RelightFlags::try_parse_from(argv).unwrap();
            let method = ProbesMethod::parse(spec, seed).unwrap().unwrap();
            assert_eq!(cli.pre.settings(seed), method.precompute, "{flags:?}");
            assert_eq!(cli.pre.settings(seed).surfels.sides, sides, "{flags:?}");
        }
        assert!(RelightFlags::try_parse_from(["relight", "--cache", "c", "--sides", "front"]).is_err());
    }

    #[test]
    fn cpca_is_on_unless_turned_off() {
        for (flags, expected) in [(&[][..], true), (&["--cpca"][..], true), (&["--cpca=off"][..], false)] {
            let mut argv = vec!["relight", "--cache", "c.probes"];
            argv.extend_from_slice(flags);
            assert_eq!(RelightFlags::try_parse_from(argv).unwrap().frame.cpca, expected, "{flags:?}");
        }
        assert!(RelightFlags::try_parse_from(["relight", "--cache", "c", "--cpca=perhaps"]).is_err());
        // fp16 by default with CPCA; --fp16=off gives f32; --cpca=off alone takes no fp16.
        for (flags, expected) in [
            (&[][..], Some(Precision::F16)),
            (&["--fp16"][..], Some(Precision::F16)),
            (&["--fp16=off"][..], Some(Precision::F32)),
            (&["--cpca=off"][..], None),
        ] {
            let mut argv = vec!["relight", "--cache", "c.probes"];
            argv.extend_from_slice(flags);
            let cpca = RelightFlags::try_parse_from(argv).unwrap().frame.validated().unwrap().0;
            assert_eq!(cpca.map(|c| c.precision), expected, "{flags:?}");
        }
    }
}
