//! The whole precompute in one value: receivers and probes ([`Layout`]), the transport α_x of
//! every receiver (hidden ones empty) and the probes' relight rays. It depends on the geometry
//! and the settings only, never on the lights or the albedo: that is what the cache
//! (`cache`) stores and what every relit frame reuses bit for bit.

use std::time::Instant;

use glam::DVec3;
use tracer::{Accel, Scene};

use crate::layout::{Layout, Step};
use crate::near_field::NearField;
use crate::placement::PlacementSettings;
use crate::relight::{RelightTable, MAX_RAYS};
use crate::surfels::{SurfelSettings, Surfels};
use crate::transport::{Transport, TransportContext, TransportSettings};
use crate::ProbesError;

/// Every setting the precompute depends on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrecomputeSettings {
    pub surfels: SurfelSettings,
    pub placement: PlacementSettings,
    pub transport: TransportSettings,
    /// Relight rays per probe.
    pub relight_rays: u32,
}

impl Default for PrecomputeSettings {
    fn default() -> Self {
        PrecomputeSettings {
            surfels: SurfelSettings::default(),
            placement: PlacementSettings::default(),
            transport: TransportSettings::default(),
            relight_rays: crate::defaults::RELIGHT_RAYS,
        }
    }
}

impl PrecomputeSettings {
    /// Checks every field (before any work).
    pub fn validate(&self) -> Result<(), ProbesError> {
        self.surfels.validate()?;
        self.placement.validate()?;
        self.transport.validate()?;
        let nc = (self.transport.order + 1) * (self.transport.order + 1);
        if !(self.relight_rays >= 4 * nc as u32 && self.relight_rays <= MAX_RAYS) {
            return Err(ProbesError::parameter(
                "relight-rays",
                format!("must be between {} and {MAX_RAYS}, got {}", 4 * nc, self.relight_rays),
            ));
        }
        Ok(())
    }
}

/// Seconds per stage of [`Precompute::build`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PrecomputeTimings {
    pub layout_s: f64,
    pub transport_s: f64,
    pub relight_s: f64,
}

impl PrecomputeTimings {
    pub fn total_s(&self) -> f64 {
        self.layout_s + self.transport_s + self.relight_s
    }
}

/// The stages [`Precompute::build`] reports to its progress callback.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Layout(Step),
    Transport,
    Relight,
}

/// Everything a relit frame needs that the lights and albedo do not change.
#[derive(Clone, Debug)]
pub struct Precompute {
    pub settings: PrecomputeSettings,
    pub surfels: Surfels,
    pub probes: Vec<DVec3>,
    /// The support radius of every probe.
    pub radius: f64,
    /// The scene's largest extent (ray offsets).
    pub scale: f64,
    /// One per surfel, in surfel order; hidden receivers have [`Transport::empty`].
    pub transports: Vec<Transport>,
    pub hidden: usize,
    /// The near field's senders per receiver (`near_field`), when `settings.transport.near`
    /// is on; the transports' α then carries only the far hits.
    pub near: Option<NearField>,
    pub table: RelightTable,
    /// How long the build took (zero when read from a cache).
    pub timings: PrecomputeTimings,
}

impl Precompute {
    /// Builds the precompute of `scene`; `progress` hears each stage as it starts.
    pub fn build(
        scene: &Scene,
        settings: &PrecomputeSettings,
        progress: &mut dyn FnMut(Stage),
    ) -> Result<Precompute, ProbesError> {
        settings.validate()?;
        let t = Instant::now();
        let layout =
            Layout::build(scene, &settings.surfels, &settings.placement, &mut |step| progress(Stage::Layout(step)))?;
        let layout_s = t.elapsed().as_secs_f64();
        let accel = Accel::build(scene).map_err(|e| ProbesError::Tracer(e.to_string()))?;
        let scale = layout.scale as f32;

        progress(Stage::Transport);
        let t = Instant::now();
        let ctx = TransportContext::new(&accel, &layout.placement.probes, layout.radius, scale, settings.transport)?;
        let (transports, hidden) = ctx.all_valid(&layout.surfels, &layout.placement.grid);
        let near = match settings.transport.near {
            None => None,
            Some(_) => {
                // A hidden receiver's transport is empty; every other one traced its directions.
                let valid: Vec<bool> = transports.iter().map(|t| t.hits + t.escaped > 0).collect();
                Some(NearField::build(&ctx, &layout.surfels, &valid)?)
            }
        };
        let transport_s = t.elapsed().as_secs_f64();

        progress(Stage::Relight);
        let t = Instant::now();
        let table = RelightTable::build(
            &accel,
            &layout.surfels,
            &layout.placement.probes,
            settings.relight_rays,
            settings.transport.order,
            scale,
        )?;
        let relight_s = t.elapsed().as_secs_f64();
        Ok(Precompute {
            settings: *settings,
            probes: layout.placement.probes.clone(),
            radius: layout.radius,
            scale: layout.scale,
            surfels: layout.surfels,
            transports,
            hidden,
            near,
            table,
            timings: PrecomputeTimings { layout_s, transport_s, relight_s },
        })
    }

    /// Drops hidden senders from the relight table's hits beside valid ones
    /// ([`RelightTable::drop_hidden_senders`]; a hidden receiver has an empty transport).
    pub fn drop_hidden_senders(&mut self) -> Result<u64, ProbesError> {
        let valid: Vec<bool> = self.transports.iter().map(|t| !t.probes.is_empty()).collect();
        self.table.drop_hidden_senders(&valid)
    }

    /// SH coefficients per probe.
    pub fn coefficients(&self) -> usize {
        self.table.coefficients
    }

    /// Bytes of the dense transport as held (f32 α and u32 probe indices).
    pub fn dense_transport_bytes(&self) -> usize {
        self.transports.iter().map(|t| t.alpha.len() * 4 + t.probes.len() * 4).sum()
    }

    /// Bytes of the near field's lists as stored, 6 B an entry (0 when it is off).
    pub fn near_field_bytes(&self) -> usize {
        self.near.as_ref().map_or(0, NearField::bytes)
    }
}
